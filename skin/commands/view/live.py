"""Drawing a :class:`~skin.commands.view.term.SkinView` live, without holding up reading.

:func:`draw_live` redraws a rich ``Live`` at most ``refresh_hz`` times a second and for at
most ``draw_share`` of the time: a redraw that took long pushes the next one back, so a
slow terminal skips redraws (counted) and never delays the threads that read the bus,
which only file samples into the view. :class:`LiveThread` runs it on a thread of its own,
for a program whose main thread is busy (``skin demo``)::

    view = SkinView(layout, scale_N=5.0)
    host.on_forces(view.update)
    with LiveThread(view, refresh_hz=4):
        time.sleep(seconds)
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rich.console import Console

    from skin.commands.view.term import SkinView

DEFAULT_REFRESH_HZ = 4.0
SNAPSHOT_SECONDS = 1.0
"""How long ``--snapshot`` watches a live source before its one frame."""
DRAW_SHARE = 0.2
SWITCH_S = 0.0005
_TICK_S = 0.05


@dataclass
class LiveStats:
    redraws: int = 0
    redraws_skipped: int = 0


@contextlib.contextmanager
def short_switch_interval(seconds: float = SWITCH_S) -> Iterator[None]:
    """Python's thread switch interval at most ``seconds`` meanwhile: a thread drawing holds
    the GIL a receiving thread needs for at most that long at a time (default 5 ms)."""
    before = sys.getswitchinterval()
    sys.setswitchinterval(min(before, seconds))
    try:
        yield
    finally:
        sys.setswitchinterval(before)


def draw_live(view: SkinView, done: Callable[[], bool], *,
              refresh_hz: float = DEFAULT_REFRESH_HZ, console: Console | None = None,
              label: Callable[[], str | None] | None = None,
              now: Callable[[], float | None] | None = None,
              stats: LiveStats | None = None, draw_share: float = DRAW_SHARE) -> LiveStats:
    """Redraw ``view`` until ``done()``, then once more; ``label()`` and ``now()`` give the
    header's time text and the bus time to draw at (default: the view's own clock)."""
    from rich.live import Live

    stats = stats if stats is not None else LiveStats()
    period = 1.0 / refresh_hz

    def frame() -> object:
        return view.renderable(now() if now is not None else None,
                               label() if label is not None else None)

    with Live(console=console, auto_refresh=False, transient=False) as live:
        due = time.monotonic()
        while not done():
            start = time.monotonic()
            if start < due:
                time.sleep(min(due - start, _TICK_S))
                continue
            live.update(frame(), refresh=True)  # type: ignore[arg-type]
            stats.redraws += 1
            after = time.monotonic()
            following = max(due + period, after + (after - start) / draw_share)
            stats.redraws_skipped += int((following - due) / period + 1e-9) - 1
            due = following
        live.update(frame(), refresh=True)  # type: ignore[arg-type]
        stats.redraws += 1
    return stats


class LiveThread:
    """:func:`draw_live` on a thread of its own, from :meth:`start` to :meth:`stop`."""

    def __init__(self, view: SkinView, *, refresh_hz: float = DEFAULT_REFRESH_HZ,
                 console: Console | None = None,
                 label: Callable[[], str | None] | None = None) -> None:
        self.view, self.refresh_hz, self.console, self.label = view, refresh_hz, console, label
        self.stats = LiveStats()
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="skin-view", daemon=True)

    def _run(self) -> None:
        try:
            draw_live(self.view, self._stop.is_set, refresh_hz=self.refresh_hz,
                      console=self.console, label=self.label, stats=self.stats)
        except Exception as err:  # a broken terminal must not take the program down
            self.error = err

    def start(self) -> LiveThread:
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop after one last redraw."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()

    def __enter__(self) -> LiveThread:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
