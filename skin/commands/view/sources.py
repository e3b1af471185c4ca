"""Where ``skin view`` gets force samples: a bus, a listen-only host, or a recording.

Live sources file samples into a :class:`~skin.commands.view.term.SkinView` from their own
threads (:class:`BusForces`: the force nodes' PDOs through a ``ForceReader``;
:class:`BusDecode`: the patches' PDOs decoded by a listen-only ``HostManager``);
:class:`Playback` replays a recording onto a private virtual bus that keeps the recorded
timestamps, into either of them. :func:`recorded_samples` reads a recording's samples
synchronously, for pictures and snapshots (deterministic: nothing depends on timing).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from itertools import count
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    import can

    from canbus.master.host import HostManager
    from canbus.master.hostconfig import HostConfig
    from canbus.tools.forcereader import ForceNodeSpec, ForceReader
    from canbus.tools.pdo_query import PdoAsker
    from canbus.tools.resistance_reader import ResistanceSample
    from canbus.tools.sample_tracker import SampleLike
    from skin.commands.view.term import SkinView

_channels = count()
_DRAIN_S = 10.0


def force_specs(config: HostConfig | None) -> list[ForceNodeSpec] | None:
    """The force nodes of a host config (node-ID, patch, COB-IDs); None: the defaults."""
    from canbus.tools.forcereader import ForceNodeSpec

    if config is None:
        return None
    return [ForceNodeSpec(p.force_node, p.node_id, p.force_cob_ids, known=True)
            for p in config.patches]


class LiveSource(Protocol):
    def start(self, view: SkinView) -> None: ...
    def stop(self) -> None: ...
    def received(self) -> int: ...
    def figures(self) -> dict[str, Any]: ...


class BusForces:
    """The force nodes' TPDOs on ``bus``, read as any master reads them."""

    def __init__(self, bus: can.BusABC, specs: list[ForceNodeSpec] | None,
                 asker: Callable[[ForceReader], PdoAsker | None] | None = None) -> None:
        from canbus.tools.forcereader import ForceReader

        self.bus = bus
        self.reader: ForceReader = ForceReader(specs)
        self.asker = asker(self.reader) if asker is not None else None
        self._notifier: can.Notifier | None = None

    def start(self, view: SkinView) -> None:
        from canbus.receiveloop import ReceiveLoop

        self.reader.on_sample(view.update)
        self.reader.start()
        listeners: list[can.Listener] = [self.reader]
        if self.asker is not None:
            listeners.append(self.asker.listener)
        self._notifier = ReceiveLoop(self.bus, listeners, timeout=0.05)
        if self.asker is not None:
            self.asker.start()

    def stop(self) -> None:
        if self.asker is not None:
            self.asker.stop()
        if self._notifier is not None:
            self._notifier.stop()  # stops the reader too: what arrived is processed
        self.reader.stop()

    def received(self) -> int:
        return self.reader.received

    def error(self) -> BaseException | None:
        return None if self._notifier is None else self._notifier.exception

    def figures(self) -> dict[str, Any]:
        r = self.reader
        return {"frames": r.received, "force_pdos": r.frames, "malformed": r.malformed,
                "samples": r.samples, "syncs": r.syncs,
                "unattributed": {f"0x{cob:03X}": n for cob, n in sorted(r.unattributed.items())}}


class BusDecode:
    """The patches' TPDOs on ``bus`` decoded in this process by a listen-only host."""

    def __init__(self, bus: can.BusABC, config: HostConfig) -> None:
        from canbus.master.host import HostManager

        self.host: HostManager = HostManager(bus, config, listen_only=True)

    def start(self, view: SkinView) -> None:
        self.host.on_forces(view.update)
        self.host.start()

    def stop(self) -> None:
        self.host.stop()

    def received(self) -> int:
        stats = self.host.dataplane.stats
        return stats.frames_in + stats.unknown_frames + stats.bus_frames

    def error(self) -> BaseException | None:
        notifier = self.host.network.notifier
        return None if notifier is None else notifier.exception

    def figures(self) -> dict[str, Any]:
        stats = self.host.stats()
        return {"frames": self.received(), "samples": stats["samples"],
                "complete_samples": stats["complete_samples"],
                "incomplete_samples": stats["incomplete_samples"],
                "late_frames": stats["late_frames"], "syncs": stats["sync_cycles"]}


def private_buses() -> tuple[can.BusABC, can.BusABC]:
    """A player bus that keeps the recorded timestamps and a bus that receives them."""
    import can

    channel = f"skin-view-{os.getpid()}-{next(_channels)}"
    player = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    return player, can.Bus(interface="virtual", channel=channel)


class Playback:
    """A recording played onto a private virtual bus (its own timestamps kept), with its
    original timing or ``fast``, into the live source ``make(bus)`` builds."""

    def __init__(self, path: str | os.PathLike[str],
                 make: Callable[[can.BusABC], BusForces | BusDecode], *, fast: bool) -> None:
        self.path, self.make, self.fast = Path(path), make, fast
        self.sent = 0
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._done = threading.Event()
        self._buses: tuple[can.BusABC, can.BusABC] | None = None
        self._source: BusForces | BusDecode | None = None
        self._thread: threading.Thread | None = None

    def start(self, view: SkinView) -> None:
        self._buses = private_buses()
        self._source = self.make(self._buses[1])
        self._source.start(view)
        self._thread = threading.Thread(target=self._play, name="skin-view-playback",
                                        daemon=True)
        self._thread.start()

    def _play(self) -> None:
        from canbus.tools.replay import Replayer

        assert self._buses is not None
        replayer = Replayer(self._buses[0], self.path, realtime=not self.fast)
        try:
            replayer.run(self._stop)
        except BaseException as err:  # a damaged recording: reported by the command
            self.error = err
        finally:
            self.sent = replayer.sent
            self._done.set()

    def finished(self) -> bool:
        """Every frame was sent and has reached the source (or the replay failed)."""
        return self._done.is_set() and (self.error is not None or self.received() >= self.sent)

    def received(self) -> int:
        return 0 if self._source is None else self._source.received()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        deadline = time.monotonic() + _DRAIN_S
        while self.error is None and self.received() < self.sent and \
                time.monotonic() < deadline:
            time.sleep(0.005)
        try:
            if self._source is not None:
                self._source.stop()
        finally:
            if self._buses is not None:
                for bus in self._buses:
                    bus.shutdown()

    def figures(self) -> dict[str, Any]:
        out = {} if self._source is None else self._source.figures()
        return out | {"sent": self.sent}


# -- recordings, synchronously -------------------------------------------------------------


@dataclass(frozen=True)
class RecordingTimes:
    """A recording's first and last frame times (bus time) and its frame count."""

    first: float
    last: float
    frames: int


def recording_times(path: str | os.PathLike[str]) -> RecordingTimes:
    from canbus.tools.recording import Recording
    from skin.errors import RecordingError

    first = last = 0.0
    frames = 0
    with Recording(path) as recording:
        for msg in recording:
            if not frames:
                first = msg.timestamp
            last = max(last, msg.timestamp)
            frames += 1
    if not frames:
        raise RecordingError(str(path), None, "holds no frame")
    return RecordingTimes(first, last, frames)


def _messages(path: str | os.PathLike[str], until: float | None) -> Iterator[can.Message]:
    from canbus.tools.recording import Recording

    with Recording(path) as recording:
        for msg in recording:
            if until is not None and msg.timestamp > until:
                return
            yield msg


def recorded_samples(path: str | os.PathLike[str], *, until: float | None = None,
                     specs: list[ForceNodeSpec] | None = None,
                     decode: HostConfig | None = None,
                     unattributed: dict[int, int] | None = None) -> list[SampleLike]:
    """Every force sample of a recording up to bus time ``until``, in time order.

    From the force nodes' PDOs (a sample is there once its last PDO is, at or before
    ``until``), or with ``decode`` a host config, from the patches' PDOs decoded by a
    listen-only host (the cycles whose SYNC is at or before ``until``). The frames no
    force node is known to send go to ``unattributed`` (COB-ID -> frames), or, without
    it, into one warning.
    """
    if decode is not None:
        return _decoded(path, until, decode)
    from canbus.tools.forcereader import ForceReader

    reader = ForceReader(specs)
    samples: list[SampleLike] = []
    reader.on_sample(samples.append)
    reader.feed(_messages(path, until))
    samples.sort(key=lambda s: s.timestamp)
    if unattributed is None:
        warn_unattributed(os.fspath(path), reader.unattributed)
    else:
        unattributed.update(reader.unattributed)
    return samples


def warn_unattributed(where: str, unattributed: dict[int, int]) -> None:
    """One line naming the force PDOs no node is known to send (left out, not guessed)."""
    if unattributed:
        import logging

        logging.getLogger("skin.commands").warning("%s: %s", where,
                                                   unattributed_text(unattributed))


def unattributed_text(unattributed: dict[int, int]) -> str:
    from canbus.tools.attribution import cob_ranges

    return (f"{sum(unattributed.values())} frames on {cob_ranges(list(unattributed))} came "
            "from no node known, when they came, to send them (a force node is known by "
            "--config, by an SDO transfer, or once its heartbeat and its whole set of default "
            "PDOs are seen together): left out, not guessed; give the host's --config "
            "HOST.toml (or --ask-by-sdo on a live bus) to read them")


def _decoded(path: str | os.PathLike[str], until: float | None,
             config: HostConfig) -> list[SampleLike]:
    import can

    from skin.errors import BusError

    frames: list[SampleLike] = []
    player, bus = private_buses()
    try:
        source = BusDecode(bus, config)
        source.host.on_forces(frames.append)
        source.host.start()
        try:
            limit = None if until is None else until + config.sync_period_ms / 1000.0
            sent = 0
            for msg in _messages(path, limit):
                if msg.is_error_frame:
                    continue
                player.send(can.Message(
                    timestamp=msg.timestamp, arbitration_id=msg.arbitration_id,
                    is_extended_id=msg.is_extended_id, is_remote_frame=msg.is_remote_frame,
                    is_fd=msg.is_fd, bitrate_switch=msg.bitrate_switch, dlc=msg.dlc,
                    data=msg.data))
                sent += 1
            deadline = time.monotonic() + _DRAIN_S
            while source.received() < sent:
                if time.monotonic() > deadline:
                    raise BusError(f"the listen-only host took {source.received()} of the "
                                   f"{sent} frames of {os.fspath(path)}")
                time.sleep(0.002)
        finally:
            source.stop()
    finally:
        player.shutdown()
        bus.shutdown()
    kept = [f for f in frames if until is None or f.timestamp <= until]
    kept.sort(key=lambda f: f.timestamp)
    return kept


def recorded_resistances(path: str | os.PathLike[str], patch: int, *,
                         until: float | None = None,
                         config: HostConfig | None = None) -> list[ResistanceSample]:
    """Patch ``patch``'s raw resistances (its own TPDOs) in a recording, in time order."""
    from canbus.tools.resistance_reader import ResistanceReader

    known, orders = [], {}
    if config is not None and any(p.node_id == patch for p in config.patches):
        from skin.commands.common.known_nodes import patch_node

        known = [patch_node(config, config.patch(patch))]
        orders = {patch: config.patch(patch).answer_order}
    reader = ResistanceReader([patch], known=known, answer_orders=orders)
    samples: list[ResistanceSample] = []
    reader.on_sample(samples.append)
    reader.feed(_messages(path, until))
    return samples
