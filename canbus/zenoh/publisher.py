"""A host's force samples, state changes, EMCYs and statistics on Zenoh, one way.

::

    with HostManager(bus, config) as host, ZenohPublisher(host, settings):
        ...   # every ForceFrame of the host is on {prefix}/{host}/{bus}/forces/{patch}

The host's callbacks (the data plane's thread for forces) only put the sample into a
bounded queue (:class:`DropOldest`) and wake the publishing thread, which encodes and
hands it to Zenoh; when Zenoh or a reader is slow the oldest samples are dropped and
counted, never waiting. Zenoh itself drops rather than blocks (congestion control
``DROP``). Nothing is subscribed or answered: what arrives on Zenoh never reaches the host.
Keys, layout and QoS: :mod:`canbus.zenoh.schema` and ``docs/zenoh.md``.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from typing import TYPE_CHECKING, Any

from canbus.master.dataplane import ForceFrame
from canbus.master.events import EmcyEvent, HostEvent, StateEvent
from canbus.master.zenoh_settings import ZenohSettings, open_zenoh
from canbus.zenoh import schema
from canbus.zenoh.contacts import CONTACTS_ENCODING, CycleGroups, contacts_key, contacts_message
from canbus.zenoh.cputime import ThreadClock, native_threads, python_threads, threads_cpu

if TYPE_CHECKING:
    import zenoh

    from canbus.master.host import HostManager

logger = logging.getLogger(__name__)

Item = tuple[ForceFrame, float] | HostEvent


class DropOldest:
    """A bounded FIFO that, when full, drops its oldest item (counted) instead of waiting."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.dropped = 0
        self.put_count = 0
        self._items: collections.deque[Item] = collections.deque()
        self._lock = threading.Lock()
        self.ready = threading.Event()

    def put(self, item: Item) -> None:
        with self._lock:
            if len(self._items) >= self.size:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self.put_count += 1
        if not self.ready.is_set():
            self.ready.set()

    def take(self) -> list[Item]:
        """Everything queued, oldest first."""
        with self._lock:
            items = list(self._items)
            self._items.clear()
        return items

    def __len__(self) -> int:
        return len(self._items)


class ZenohPublisher:
    """Publishes what ``host`` makes on Zenoh as ``settings`` say (module docstring).

    ``session``: a Zenoh session to publish on (the caller's, not closed here); by
    default one is opened from ``settings`` at :meth:`start` and closed at :meth:`stop`.
    ``measure_cpu``: also time the hand-over on the host's threads (two reads of the
    thread's CPU clock per sample; :meth:`cpu_seconds`), for benchmarks.
    """

    def __init__(self, host: HostManager, settings: ZenohSettings | None = None, *,
                 session: zenoh.Session | None = None, measure_cpu: bool = False) -> None:
        self.host = host
        self.settings = settings or ZenohSettings()
        self.host_name = self.settings.host_name
        self._host_bytes = self.host_name.encode()
        self.queue = DropOldest(self.settings.queue_size)
        self.session = session
        self._own_session = session is None
        self._publishers: dict[int, tuple[Any, bytes]] = {}  # patch -> (publisher, bus utf-8)
        self._contacts: dict[str, tuple[Any, CycleGroups]] = {}  # bus -> its contact list's
        self.contacts_sent = 0
        self._events: Any = None
        self._stats_pub: Any = None
        self._token: Any = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._clock = ThreadClock()
        self._before: set[int] | None = None  # threads before our session opened
        self.sent = 0
        self.events_sent = 0
        self.put_errors = 0
        self.enqueue_ns = 0  # CPU the host's threads spent handing samples over
        # one bound method each, kept: the host removes a callback by identity
        self._forces_cb = self._on_forces_timed if measure_cpu else self.on_forces
        self._events_cb = self.queue.put

    # -- lifecycle ---------------------------------------------------------------------

    def __enter__(self) -> ZenohPublisher:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> None:
        """Open the session, declare a publisher per patch, subscribe to the host."""
        try:
            self._start()
        except BaseException:
            self.stop()
            raise

    def _start(self) -> None:
        import zenoh

        self._before = native_threads() if self.session is None else None
        if self.session is None:
            self.session = open_zenoh(self.settings)
        prefix = self.settings.prefix
        for patch in self.host.config.patches:
            key = schema.forces_key(prefix, self.host_name, patch.bus, patch.node_id)
            publisher = self.session.declare_publisher(
                key, encoding=zenoh.Encoding(schema.FORCE_ENCODING),
                congestion_control=zenoh.CongestionControl.DROP,
                priority=zenoh.Priority.DATA_HIGH, express=self.settings.express)
            self._publishers[patch.node_id] = (publisher, patch.bus.encode())
        placed = {p.bus for p in self.host.config.patches if p.placement is not None}
        for bus in sorted(placed):  # the robot-wide contact list (docs/robot.md)
            publisher = self.session.declare_publisher(
                contacts_key(prefix, self.host_name, bus),
                encoding=zenoh.Encoding(CONTACTS_ENCODING),
                congestion_control=zenoh.CongestionControl.DROP,
                priority=zenoh.Priority.DATA_HIGH, express=self.settings.express)
            patches = sum(1 for p in self.host.config.patches if p.bus == bus)
            self._contacts[bus] = (publisher, CycleGroups(patches))
        self._stats_pub = self.session.declare_publisher(
            schema.stats_key(prefix, self.host_name),
            encoding=zenoh.Encoding(schema.EVENT_ENCODING),
            congestion_control=zenoh.CongestionControl.DROP, priority=zenoh.Priority.DATA_LOW)
        self._token = self.session.liveliness().declare_token(
            schema.alive_key(prefix, self.host_name))
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="zenoh-publisher", daemon=True)
        self._thread.start()
        for health_patch, health in self.host.health().items():
            self.queue.put(StateEvent(health_patch, health.bus, health.state, "", health.error,
                                      time.time()))
        self.host.on_forces(self._forces_cb)
        self.host.on_event(self._events_cb)

    def stop(self) -> None:
        """Stop taking samples, publish what is queued, close what :meth:`start` opened."""
        self.host.remove_callback(self._forces_cb)
        self.host.remove_event_callback(self._events_cb)
        if self._thread is not None:
            self._stop.set()
            self.queue.ready.set()
            self._thread.join()
            self._thread = None
        if self.session is None:
            return
        self._publish_stats()
        for bus, (publisher, groups) in self._contacts.items():
            for frames in groups.rest():
                self._put_contacts(publisher, bus, frames)
            publisher.undeclare()
        self._contacts.clear()
        for publisher, _ in self._publishers.values():
            publisher.undeclare()
        self._publishers.clear()
        for entity in (self._stats_pub, self._token):
            if entity is not None:
                entity.undeclare()
        self._stats_pub = self._token = None
        if self._own_session and self.session is not None:
            self.session.close()
            self.session = None

    # -- the host's threads ------------------------------------------------------------

    def on_forces(self, frame: ForceFrame) -> None:
        """The host's force callback: queue the frame with the time it was handed out."""
        self.queue.put((frame, time.time()))

    def _on_forces_timed(self, frame: ForceFrame) -> None:
        start = time.thread_time_ns()
        self.queue.put((frame, time.time()))
        self.enqueue_ns += time.thread_time_ns() - start

    # -- the publishing thread ---------------------------------------------------------

    def _run(self) -> None:
        period = self.settings.stats_period_s
        next_stats = time.monotonic() + period
        ready = self.queue.ready
        while True:
            ready.wait(max(0.0, next_stats - time.monotonic()))
            ready.clear()
            with self._clock:
                for item in self.queue.take():
                    self._publish(item)
            if time.monotonic() >= next_stats:
                self._publish_stats()
                next_stats = max(next_stats + period, time.monotonic())
            if self._stop.is_set() and not len(self.queue):
                return

    def _publish(self, item: Item) -> None:
        try:
            if isinstance(item, tuple):
                frame, published = item
                publisher, bus = self._publishers[frame.patch]
                publisher.put(schema.encode_forces(frame, self._host_bytes, bus, published,
                                                   time.time()))
                self.sent += 1
                if self._contacts:
                    self._group(frame)
            else:
                self._publish_event(item)
        except Exception:
            self.put_errors += 1
            logger.exception("zenoh: could not publish %r", type(item).__name__)

    def _group(self, frame: ForceFrame) -> None:
        bus = self.host.config.patch(frame.patch).bus
        mine = self._contacts.get(bus)
        if mine is not None:
            for frames in mine[1].add(frame):
                self._put_contacts(mine[0], bus, frames)

    def _put_contacts(self, publisher: Any, bus: str, frames: list[ForceFrame]) -> None:
        publisher.put(contacts_message(self.host_name, bus, frames))
        self.contacts_sent += 1

    def _publish_event(self, event: HostEvent) -> None:
        assert self.session is not None
        prefix, host = self.settings.prefix, self.host_name
        if isinstance(event, StateEvent):
            kind = "state"
            fields = {"host": host, "bus": event.bus, "patch": event.patch,
                      "state": event.state, "previous": event.previous or None,
                      "error": event.error, "time": event.time}
        else:
            assert isinstance(event, EmcyEvent)
            kind = "emcy"
            fields = {"host": host, "bus": event.bus, "patch": event.patch, "code": event.code,
                      "register": event.register, "data": event.data, "time": event.time}
        import zenoh

        self.session.put(schema.event_key(prefix, host, event.bus, kind, event.patch),
                         schema.encode_event(fields),
                         encoding=zenoh.Encoding(schema.EVENT_ENCODING),
                         congestion_control=zenoh.CongestionControl.DROP,
                         priority=zenoh.Priority.INTERACTIVE_HIGH)
        self.events_sent += 1

    def _publish_stats(self) -> None:
        if self._stats_pub is None:
            return
        patches = [{"patch": p.node_id, "bus": p.bus, "force_node": p.force_node,
                    "mode": p.mode, "position_m": list(p.position_m) if p.position_m else None}
                   for p in self.host.config.patches]
        fields = {"host": self.host_name, "time": time.time(), "stats": self.host.stats(),
                  "zenoh": self.counters(), "patches": patches}
        try:
            self._stats_pub.put(schema.encode_event(fields))
        except Exception:
            self.put_errors += 1
            logger.exception("zenoh: could not publish the statistics")

    # -- figures -----------------------------------------------------------------------

    def counters(self) -> dict[str, int]:
        """Samples queued, sent, dropped (queue full), events sent, errors."""
        return {"queued": self.queue.put_count, "sent": self.sent,
                "dropped": self.queue.dropped, "events_sent": self.events_sent,
                "contacts_sent": self.contacts_sent, "put_errors": self.put_errors}

    def cpu_seconds(self) -> dict[str, float]:
        """CPU spent publishing: the publishing thread, Zenoh's own threads, and the
        host's threads handing samples over (0 unless ``measure_cpu``)."""
        return {"thread": self._clock.seconds, "zenoh": threads_cpu(self.zenoh_threads()),
                "enqueue": self.enqueue_ns / 1e9}

    def zenoh_threads(self) -> set[int]:
        """Zenoh's own threads: the native threads that appeared with our session (none
        when the session was the caller's: they cannot be told apart then)."""
        if self._before is None:
            return set()
        return native_threads() - self._before - python_threads()
