"""``TimedBus``: python-can's interface ``timed``, a node on a bit-timed simulated wire.

    bus = can.Bus(interface="timed", channel="skin0", bitrate=1_000_000,
                  fd=True, data_bitrate=5_000_000)

Buses on the same channel in one process share one wire (``canbus.timed.wire``); each is a
node with its own FIFO transmit queue. See docs/timedbus.md.
"""

from __future__ import annotations

from typing import Any

import can
from can.typechecking import AutoDetectedConfig, Channel

from canbus import framebits
from canbus.timed import message
from canbus.timed.channels import DEFAULT_BITRATE, join, leave, open_channels
from canbus.timed.errors import TimedBusConfigError, TimedBusError
from canbus.timed.faults import BitErrors
from canbus.timed.node import Pending
from canbus.timed.stats import NodeStats, WireStats

MAX_BITRATE, MAX_DATA_BITRATE = 1_000_000, 20_000_000
DEFAULT_RESOLUTION_S = 0.0005


def _number(value: Any) -> Any:
    """python-can's configuration from the environment gives numbers as text."""
    return int(value) if isinstance(value, str) and value.strip().isdigit() else value


def _bitrates(bitrate: int | None, data_bitrate: int | None, fd: bool,
              timing: Any) -> tuple[int, int | None, bool]:
    if isinstance(timing, can.BitTimingFd):
        bitrate, data_bitrate, fd = timing.nom_bitrate, timing.data_bitrate, True
    elif isinstance(timing, can.BitTiming):
        bitrate = timing.bitrate
    elif timing is not None:
        raise TimedBusConfigError(f"timing must be a can.BitTiming or can.BitTimingFd, "
                                  f"got {type(timing).__name__}")
    bitrate = DEFAULT_BITRATE if bitrate is None else _number(bitrate)
    data_bitrate = None if data_bitrate is None else _number(data_bitrate)
    if not (isinstance(bitrate, int) and 0 < bitrate <= MAX_BITRATE):
        raise TimedBusConfigError(f"bitrate must be an int in 1..{MAX_BITRATE} bit/s, "
                                  f"got {bitrate!r}")
    if data_bitrate is not None and not (
            isinstance(data_bitrate, int) and bitrate <= data_bitrate <= MAX_DATA_BITRATE):
        raise TimedBusConfigError(f"data_bitrate must be an int in {bitrate}..{MAX_DATA_BITRATE} "
                                  f"bit/s (not below the nominal bitrate), got {data_bitrate!r}")
    return bitrate, data_bitrate, fd


class TimedBus(can.BusABC):
    """A CAN / CAN FD node on a simulated wire that keeps time (python-can interface ``timed``).

    :param channel: a name (any hashable); buses on the same channel in this process share
        a wire.
    :param bitrate: nominal bitrate in bit/s (default 1 000 000); every bus of a channel
        must give the same.
    :param fd: this node speaks CAN FD (it may send FD frames; it receives them).
    :param data_bitrate: CAN FD data-phase bitrate (default 5 000 000, or the channel's).
    :param timing: a ``can.BitTiming`` / ``can.BitTimingFd`` instead of the bitrates.
    :param realtime: True (default): the wire's clock is ``time.time()`` and frames take
        their real time. False: simulated time, as fast as the readers drive it.
    :param receive_own_messages: this node also receives the frames it sent.
    :param tx_queue_size: frames the transmit queue holds (default 256); ``send`` waits
        for room up to its timeout, then raises ``can.CanOperationError``.
    :param rx_queue_size: frames the receive queue holds (0, the default: no limit); a
        frame arriving at a full queue is lost here only, and counted.
    :param acknowledge: this node acknowledges frames (False: it listens but does not, as
        a broken or listen-only node); settable later as :attr:`acknowledge`.
    :param error_probability: chance that an attempt of a frame this node sends is hit by
        a bit error (error frame, retransmission, error counters); settable later.
    :param error_seed: seed of the bit-error draws (reproducible runs).
    :param receive_error_frames: ``recv`` also returns error frames (``is_error_frame``).
    :param node_name: the node's name in the statistics (default ``node<k>``).
    :param stats_window_s: span of the windowed load of :meth:`wire_stats` (the first bus
        of a channel sets it; default 1 s).
    :param resolution_s: real time: the least time between two timed wake-ups of the
        readers that run the wire (default 0.0005 s; the first bus of a channel sets it).
        Frames that end closer together are delivered together, each stamped with its own
        end; a frame after an idle spell is delivered at its end. 0 wakes a reader at every
        frame's end, at about 15 us of CPU per wake-up.
    """

    def __init__(self, channel: Channel = "skin0", can_filters: Any = None, *,
                 bitrate: int | None = None, fd: bool = False, data_bitrate: int | None = None,
                 timing: Any = None, realtime: bool = True, receive_own_messages: bool = False,
                 tx_queue_size: int = 256, rx_queue_size: int = 0, acknowledge: bool = True,
                 error_probability: float = 0.0, error_seed: int | None = None,
                 receive_error_frames: bool = False, node_name: str | None = None,
                 stats_window_s: float = 1.0, resolution_s: float = DEFAULT_RESOLUTION_S,
                 **kwargs: Any) -> None:
        bitrate, data_bitrate, fd = _bitrates(bitrate, data_bitrate, bool(fd), timing)
        if not (isinstance(tx_queue_size, int) and tx_queue_size >= 1):
            raise TimedBusConfigError(f"tx_queue_size must be at least 1, got {tx_queue_size!r}")
        if not (isinstance(rx_queue_size, int) and rx_queue_size >= 0):
            raise TimedBusConfigError(f"rx_queue_size must be 0 (no limit) or more, "
                                      f"got {rx_queue_size!r}")
        if not stats_window_s > 0:
            raise TimedBusConfigError(f"stats_window_s must be positive, got {stats_window_s}")
        if not 0 <= resolution_s <= 0.1:
            raise TimedBusConfigError(f"resolution_s must be in 0..0.1 s, got {resolution_s}")
        try:
            errors = BitErrors(float(error_probability), error_seed)
        except (TypeError, ValueError) as err:
            raise TimedBusConfigError(str(err)) from err
        self._wire, self._node = join(
            channel, bitrate=bitrate, data_bitrate=data_bitrate, fd=fd,
            realtime=bool(realtime), window_s=float(stats_window_s),
            resolution_s=float(resolution_s), name=node_name,
            receive_own=bool(receive_own_messages),
            receive_error_frames=bool(receive_error_frames), acknowledge=bool(acknowledge),
            tx_limit=tx_queue_size, rx_limit=rx_queue_size, errors=errors)
        self.channel_id = channel
        self.channel_info = (f"timed channel {channel!r}, {bitrate} bit/s"
                             + (f", CAN FD data phase {self._wire.data_bitrate} bit/s" if fd
                                else ""))
        self._can_protocol = can.CanProtocol.CAN_FD if fd else can.CanProtocol.CAN_20
        self._fd = fd
        try:
            super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        except BaseException:
            leave(self._wire, self._node)
            raise

    # ------------------------------------------------------------------ python-can

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Queue ``msg`` for the wire (FIFO); wait up to ``timeout`` s for room in the queue."""
        if self._is_shutdown:
            raise TimedBusError("Cannot operate on a closed bus")
        self._wire.submit(self._node, self._pending(msg), timeout)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """The next frame that passes the filters, waiting up to ``timeout`` seconds.

        In real time a reader waiting here runs the wire (see ``canbus.timed.wire``). In
        simulated time the timeout is simulated time while the wire has frames to carry,
        real time while it waits for another thread to send.
        """
        self._check_open()
        msg = self._wire.receive(self._node, timeout,
                                 None if self._filters is None else self._matches_filters)
        if msg is None:
            self._check_open()  # a bus shut down while its reader waited says so
        return msg

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        self._check_open()
        return self._wire.receive(self._node, timeout), False

    def shutdown(self) -> None:
        super().shutdown()
        leave(self._wire, self._node)

    def flush_tx_buffer(self) -> None:
        self._wire.flush(self._node)

    @property
    def state(self) -> can.BusState:
        """ACTIVE, PASSIVE (error passive) or ERROR (bus off)."""
        return self._node.state

    @state.setter
    def state(self, new_state: can.BusState) -> None:
        raise NotImplementedError("a timed bus's state follows its error counters; "
                                  "use acknowledge=False for a node that only listens")

    @staticmethod
    def _detect_available_configs() -> list[AutoDetectedConfig]:
        return [{"interface": "timed", "channel": channel}  # type: ignore[typeddict-item]
                for channel in open_channels()]

    # ------------------------------------------------------------------ timed bus

    @property
    def acknowledge(self) -> bool:
        """Whether this node acknowledges the frames it receives."""
        return self._node.acknowledge

    @acknowledge.setter
    def acknowledge(self, value: bool) -> None:
        self._wire.update(self._node, acknowledge=bool(value))

    @property
    def error_probability(self) -> float:
        """Chance of a bit error on each attempt of a frame this node sends."""
        return self._node.errors.probability

    @error_probability.setter
    def error_probability(self, value: float) -> None:
        if not 0.0 <= value <= 1.0:
            raise TimedBusConfigError(f"error_probability must be in 0..1, got {value}")
        self._wire.update(self._node, error_probability=float(value))

    @property
    def realtime(self) -> bool:
        return self._wire.realtime

    @property
    def bitrate(self) -> int:
        return self._wire.bitrate

    @property
    def data_bitrate(self) -> int | None:
        return self._wire.data_bitrate

    def now(self) -> float:
        """The wire's clock (``time.time()`` in real time)."""
        return self._wire.now()

    def advance(self, seconds: float) -> None:
        """Simulated time only: let ``seconds`` pass, carrying the frames due meanwhile."""
        self._wire.advance(seconds)

    def wire_stats(self, window_s: float | None = None) -> WireStats:
        """The channel's wire: load, frames, bits, errors, per node (a frozen snapshot)."""
        return self._wire.stats(window_s)

    def node_stats(self) -> NodeStats:
        """This node: frames sent and received, losses, error counters and state."""
        return self._wire.node_stats(self._node)

    # ------------------------------------------------------------------ internals

    def _check_open(self) -> None:
        if self._is_shutdown or not self._node.open:
            raise TimedBusError("Cannot operate on a closed bus")

    def _pending(self, msg: can.Message) -> Pending:
        can_id, dlc = msg.arbitration_id, msg.dlc
        if not (msg.is_extended_id or msg.is_remote_frame or msg.is_fd or msg.is_error_frame):
            data = bytes(msg.data or b"")  # the frame sent most: a base-format classic data frame
            if 0 <= can_id <= 0x7FF and len(data) <= 8:
                return Pending(message.copy(msg, data, self.channel_id, 0.0, True, dlc),
                               can_id, 0, len(data), data, can_id << 21)
        return self._checked(msg)

    def _checked(self, msg: can.Message) -> Pending:
        """Any other frame, checked (the error names what is wrong)."""
        if msg.is_error_frame:
            raise TimedBusError("a controller cannot send an error frame")
        if msg.is_fd and not self._fd:
            raise TimedBusError(f"CAN FD frame 0x{msg.arbitration_id:X} on a classic bus "
                                "(open the bus with fd=True)")
        data = bytes(msg.data or b"")
        flags = (framebits.F_EXTENDED * msg.is_extended_id | framebits.F_REMOTE
                 * msg.is_remote_frame | framebits.F_FD * msg.is_fd
                 | framebits.F_BRS * (msg.is_fd and msg.bitrate_switch)
                 | framebits.F_ESI * (msg.is_fd and msg.error_state_indicator))
        dlc = len(data) if msg.is_fd or not msg.is_remote_frame else msg.dlc
        try:
            if msg.is_fd:
                data += bytes(framebits.FD_LENGTHS[framebits.fd_dlc(len(data))] - len(data))
            framebits.check(msg.arbitration_id, len(data), flags, dlc)
        except ValueError as err:
            raise TimedBusError(f"cannot send frame 0x{msg.arbitration_id:X}: {err}") from err
        key = framebits.arbitration_key(msg.arbitration_id, extended=msg.is_extended_id,
                                        remote=msg.is_remote_frame)
        return Pending(message.snapshot(msg, data, self.channel_id), msg.arbitration_id, flags,
                       dlc, data, key)
