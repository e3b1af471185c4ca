"""An MCAP recording (ROS 2 profile, CDR): the CAN frames and, where the command decodes,
the force samples, written as a stream by :class:`McapSegment`, one file of a
:class:`~canbus.tools.recorder.Recorder`.

The ``mcap`` library's writer builds zstd-compressed chunks in memory; each checkpoint
(every :data:`~canbus.tools.recorder.FLUSH_S`) closes the chunk and appends it, with its
message indexes, to the file in one write; closing writes the summary (schemas,
channels, statistics, chunk indexes) and the footer. So the file under its final name
is, at every moment, an MCAP file of whole chunks: a kill -9 loses what came since the
last checkpoint and, if it lands inside the write, leaves that last chunk cut (a reader
that reads the file as a stream gets every chunk before it; ``Recording(path,
partial=True)`` does). docs/mcap.md lists the topics and fields.
"""

from __future__ import annotations

import os
from pathlib import Path

import can
import numpy as np

from canbus.tools import mcap_messages as m
from canbus.tools.sample_wire import ContactFields, Sample, contact_fields
from canbus.tools.segments import Segment
from skin.constants import DEFAULT_CONSTANTS
from skin.contact import taxel_xy
from skin.inputs.outputs import create_in_place

CHUNK_BYTES = 4 << 20
"""A chunk closes at this size even before a checkpoint (a burst)."""
_MESSAGE_RECORD = 31  # a Message record's bytes besides its data (opcode, length, header)
_DEFAULT_PITCH_M = DEFAULT_CONSTANTS.taxel_pitch_m


class _Sink:
    """The writer's output: what it writes waits here for the segment's next write; its
    offsets (tell) count from the start of the file."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.offset = 0

    def write(self, data: bytes) -> int:
        self.data += data
        self.offset += len(data)
        return len(data)

    def tell(self) -> int:
        return self.offset

    def flush(self) -> None:
        pass

    def take(self) -> bytes:
        out = bytes(self.data)
        self.data.clear()
        return out


class McapSegment(Segment):
    """One .mcap file of a recording: frames through :meth:`writer`, force samples through
    :meth:`write_forces`; complete up to the last checkpoint (see the module)."""

    def __init__(self, path: Path, channel: str | None,
                 placements: list[m.Placement] | None = None) -> None:
        writer_module = m.require_mcap()
        super().__init__(path)
        self._channel = channel or "can0"
        self._sink = _Sink()
        self._mcap = writer_module.Writer(self._sink, chunk_size=CHUNK_BYTES,
                                          compression=writer_module.CompressionType.ZSTD)
        self._mcap.start(profile="ros2", library="canskin")
        self._schemas: dict[str, int] = {}
        self._topics: dict[str, int] = {}
        self._frames = m.FrameEncoder(self._channel)
        self._xy = {p.patch: taxel_xy(p.pitch_m) for p in placements or []}
        self._default_xy = taxel_xy(_DEFAULT_PITCH_M)
        self._tf_static = placements or None  # written at the first message's time
        self._end = 0
        self._unwritten = 0  # message bytes in the open chunk

        def header(fd: int) -> None:
            self._fd = fd
            self._write(self._sink.take())

        self._fd = create_in_place(path, header)
        self._listener = _FrameListener(self)

    def _topic(self, topic: str, schema: str, metadata: dict[str, str] | None = None) -> int:
        channel = self._topics.get(topic)
        if channel is None:
            schema_id = self._schemas.get(schema)
            if schema_id is None:
                schema_id = self._mcap.register_schema(schema, "ros2msg",
                                                       m.SCHEMAS[schema].encode())
                self._schemas[schema] = schema_id
            channel = self._mcap.register_channel(topic, "cdr", schema_id, metadata or {})
            self._topics[topic] = channel
        return channel

    def _write_tf_static(self, ns: int) -> None:
        placements, self._tf_static = self._tf_static or [], None
        qos = ("- history: 3\n  depth: 0\n  reliability: 1\n  durability: 1\n  deadline:\n"
               "    sec: 2147483647\n    nsec: 4294967295\n  lifespan:\n    sec: 2147483647\n"
               "    nsec: 4294967295\n  liveliness: 1\n  liveliness_lease_duration:\n"
               "    sec: 2147483647\n    nsec: 4294967295\n"
               "  avoid_ros_namespace_conventions: false\n")
        channel = self._topic(m.TF_STATIC_TOPIC, m.TF, {"offered_qos_profiles": qos})
        self._add(channel, ns, m.encode_tf_static(ns, placements), ns)

    def writer(self) -> can.Listener:
        return self._listener

    def add_frame(self, msg: can.Message) -> None:
        ns = m.stamp_ns(msg.timestamp)
        if self._tf_static is not None:
            self._write_tf_static(ns)
        channel = msg.channel if isinstance(msg.channel, str) else self._channel
        if msg.is_fd:
            data = m.encode_fd_frame(ns, channel, msg.arbitration_id, msg.is_extended_id,
                                     msg.is_error_frame, bytes(msg.data))
            self._add(self._topic(m.FD_FRAMES_TOPIC, m.FD_FRAME), ns, data, ns)
            return
        encoder = self._frames if channel == self._channel else m.FrameEncoder(channel)
        data = encoder.encode(ns, msg.arbitration_id, msg.is_remote_frame, msg.is_extended_id,
                              msg.is_error_frame, msg.dlc, bytes(msg.data))
        self._add(self._topic(m.FRAMES_TOPIC, m.FRAME), ns, data, ns)

    def write_forces(self, frame: Sample, contact: ContactFields | None = None) -> None:
        """One patch's sample: its taxels, and its contact summary where it has one
        (``contact``, else the frame's own)."""
        if contact is None:
            contact = contact_fields(frame.contact)
        ns = m.stamp_ns(frame.timestamp)
        if self._tf_static is not None:
            self._write_tf_static(ns)
        patch, where = frame.patch, m.patch_frame(frame.patch)
        points = np.zeros(len(frame.valid), dtype=m.TAXEL_DTYPE)
        xy = self._xy.get(patch, self._default_xy)
        points["x"], points["y"] = xy[:, 0], xy[:, 1]
        force = frame.force_N
        points["fx"], points["fy"], points["fz"] = force[:, 0], force[:, 1], force[:, 2]
        points["valid"], points["reason"] = frame.valid, frame.reason
        points["time_s"], points["cycle"] = frame.timestamp, frame.cycle
        points["sync_counter"], points["force_node"] = frame.sync_counter, frame.force_node
        points["flags"] = m.COMPLETE * frame.complete + m.PUBLISHED * frame.published
        points["patch"] = patch
        if contact is not None:
            points["contact"], points["slip"] = contact.contact_taxels, contact.taxel_slip
        add = self._add
        add(self._topic(m.patch_topic(patch, "taxels"), m.TAXELS), ns,
            m.encode_taxels(ns, where, points), ns)
        if contact is None:
            return
        add(self._topic(m.patch_topic(patch, "wrench"), m.WRENCH), ns,
            m.encode_wrench(ns, where, contact.force_N, contact.torque_Nm), ns)
        if contact.cop_defined:
            x, y = contact.cop_m.tolist()
            add(self._topic(m.patch_topic(patch, "cop"), m.POINT), ns,
                m.encode_point(ns, where, x, y, 0.0), ns)
        add(self._topic(m.patch_topic(patch, "contact_state"), m.STATE), ns,
            m.encode_uint8(contact.state_byte), ns)

    def _add(self, channel: int, ns: int, data: bytes, publish_ns: int) -> None:
        self._mcap.add_message(channel, ns, data, publish_ns)
        self._unwritten += len(data) + _MESSAGE_RECORD

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            done = os.pwrite(self._fd, view, self._end)
            view, self._end = view[done:], self._end + done

    def size(self) -> int:
        """The file so far and the messages of the open chunk, uncompressed."""
        return self._end + len(self._sink.data) + self._unwritten

    def buffered(self) -> int:
        return len(self._sink.data) + self._unwritten

    def checkpoint(self) -> None:
        self._mcap.flush()  # the open chunk closes: a whole chunk and its indexes
        self._unwritten = 0
        data = self._sink.take()
        if data:
            self._write(data)

    def close(self) -> None:
        try:
            self._mcap.finish()
            self._write(self._sink.take())
            os.fsync(self._fd)
        finally:
            os.close(self._fd)


class _FrameListener(can.Listener):
    def __init__(self, segment: McapSegment) -> None:
        self.on_message_received = segment.add_frame  # type: ignore[method-assign]

    def on_message_received(self, msg: can.Message) -> None:  # replaced in __init__
        raise NotImplementedError

