"""Reading the skin from Zenoh: the host's own ``ForceFrame``s, from any number of hosts.

::

    from canbus.zenoh.reader import subscribe

    with subscribe(patch=3) as sub:              # or host=, bus=, a key expression, nothing
        for frame in sub.frames(timeout=1.0):    # ForceFrame, as host.frames() gives
            ...
        sub.latest()                             # {(host, patch): the newest Sample}

By default a subscription queues every sample (up to ``queue_size``; past that new ones
are counted in ``dropped`` and not kept); ``ring=N`` keeps only the newest N (older ones
dropped and counted), for a reader that wants the present rather than the past.
Samples whose payload is not a force sample of a known schema are counted in
``rejected`` and logged once per key. Zenoh calls back on its own thread; the frames are
decoded there.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

from canbus.master.dataplane import ForceFrame
from canbus.master.zenoh_settings import ZenohSettings, open_zenoh
from canbus.zenoh import schema
from canbus.zenoh.schema import Sample

if TYPE_CHECKING:
    import zenoh

logger = logging.getLogger(__name__)

DEFAULT_QUEUE = 65536


class Subscription:
    """Force samples on one key expression (see :func:`subscribe`)."""

    def __init__(self, session: zenoh.Session, key: str, *, own_session: bool,
                 ring: int | None = None, queue_size: int = DEFAULT_QUEUE,
                 on_sample: Callable[[Sample], None] | None = None) -> None:
        if ring is not None and ring < 1:
            raise ValueError(f"ring must hold at least 1 sample, got {ring}")
        if queue_size < 1:
            raise ValueError(f"queue_size must be at least 1, got {queue_size}")
        self.key = key
        self.session = session
        self.ring = ring
        self.queue_size = ring if ring is not None else queue_size
        self.on_sample = on_sample
        self.received = 0
        self.rejected = 0
        self.dropped = 0
        self.callback_errors = 0
        self._own_session = own_session
        self._samples: collections.deque[Sample] = collections.deque()
        self._latest: dict[tuple[str, int], Sample] = {}
        self._warned: set[str] = set()
        self._ready = threading.Condition()
        self._closed = False
        self._subscriber = session.declare_subscriber(key, self._on_zenoh)

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop receiving; iterators end once they have what was received."""
        if self._closed:
            return
        self._closed = True
        self._subscriber.undeclare()
        if self._own_session:
            self.session.close()
        with self._ready:
            self._ready.notify_all()

    # -- Zenoh's thread ----------------------------------------------------------------

    def _on_zenoh(self, zsample: zenoh.Sample) -> None:
        received = time.time()
        try:
            sample = schema.decode_forces(zsample.payload.to_bytes(), received)
        except schema.SchemaError as err:
            self.rejected += 1
            key = str(zsample.key_expr)
            if key not in self._warned:
                self._warned.add(key)
                logger.warning("zenoh: %s: not a force sample: %s", key, err)
            return
        self.received += 1
        self._latest[(sample.host, sample.frame.patch)] = sample
        if self.on_sample is not None:
            try:
                self.on_sample(sample)
            except Exception:
                self.callback_errors += 1
                logger.exception("zenoh: sample callback %r failed", self.on_sample)
        with self._ready:
            if len(self._samples) >= self.queue_size:
                self.dropped += 1
                if self.ring is None:
                    return
                self._samples.popleft()
            self._samples.append(sample)
            self._ready.notify()

    # -- the reader's side -------------------------------------------------------------

    def samples(self, timeout: float | None = 1.0) -> Iterator[Sample]:
        """Samples as they come, oldest first; ends after ``timeout`` s without one
        (``None``: never) or when the subscription is closed and drained."""
        while True:
            with self._ready:
                if not self._samples and not self._closed:
                    self._ready.wait_for(lambda: self._samples or self._closed, timeout)
                if not self._samples:
                    return
                sample = self._samples.popleft()
            yield sample

    def frames(self, timeout: float | None = 1.0) -> Iterator[ForceFrame]:
        """The :class:`ForceFrame` of each sample (see :meth:`samples`)."""
        for sample in self.samples(timeout):
            yield sample.frame

    def __iter__(self) -> Iterator[ForceFrame]:
        return self.frames(timeout=None)

    def newest(self) -> list[Sample]:
        """What is held now, oldest first, without taking it."""
        with self._ready:
            return list(self._samples)

    def latest(self) -> dict[tuple[str, int], Sample]:
        """The newest sample of every (host, patch) seen so far."""
        return dict(self._latest)

    def counters(self) -> dict[str, int]:
        return {"received": self.received, "rejected": self.rejected,
                "dropped": self.dropped, "callback_errors": self.callback_errors,
                "held": len(self._samples)}


def open_session(settings: ZenohSettings | None = None) -> zenoh.Session:
    """A reader's Zenoh session: ``settings`` (default: connect to this machine's host)."""
    return open_zenoh(settings or ZenohSettings(), reader=True)


def subscribe(key: str | None = None, *, host: str | None = None, bus: str | None = None,
              patch: int | None = None, prefix: str | None = None,
              settings: ZenohSettings | None = None, session: zenoh.Session | None = None,
              ring: int | None = None, queue_size: int = DEFAULT_QUEUE,
              on_sample: Callable[[Sample], None] | None = None) -> Subscription:
    """Subscribe to force samples: ``key`` (a key expression), or the one patch, bus or
    host named (None: any), under ``prefix`` (default: ``settings.prefix``).

    ``session``: a Zenoh session to use (kept open on close); by default one is opened
    from ``settings`` (default: connect to ``tcp/127.0.0.1:7447``, no scouting).
    ``on_sample(sample)`` is called on Zenoh's thread for every sample.
    """
    settings = settings or ZenohSettings()
    if key is None:
        key = schema.forces_selector(prefix or settings.prefix, host=host, bus=bus, patch=patch)
    own = session is None
    zsession = open_session(settings) if session is None else session
    try:
        return Subscription(zsession, key, own_session=own, ring=ring, queue_size=queue_size,
                            on_sample=on_sample)
    except BaseException:
        if own:
            zsession.close()
        raise


def subscribe_events(callback: Callable[[str, dict[str, Any]], None], *,
                     host: str | None = None, prefix: str | None = None,
                     settings: ZenohSettings | None = None,
                     session: zenoh.Session) -> list[Any]:
    """Call ``callback(key, fields)`` for every state, EMCY and statistics event of
    ``host`` (None: every host); returns the Zenoh subscribers (undeclare them to stop).
    Events that are not a known schema's are logged and skipped."""
    prefix = prefix or (settings or ZenohSettings()).prefix
    who = host or "*"

    def on_event(zsample: zenoh.Sample) -> None:
        key = str(zsample.key_expr)
        try:
            fields = schema.decode_event(zsample.payload.to_bytes())
        except schema.SchemaError as err:
            logger.warning("zenoh: %s: not an event: %s", key, err)
            return
        callback(key, fields)

    keys = [f"{prefix}/{who}/*/state/*", f"{prefix}/{who}/*/emcy/*",
            schema.stats_key(prefix, who)]
    return [session.declare_subscriber(k, on_event) for k in keys]
