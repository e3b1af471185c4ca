"""The ROS 2 messages of a canskin MCAP recording: their definitions (``ros2msg`` text, as
the file carries them) and their CDR encoding, little-endian, written by hand with
``struct`` (the frames are the hot path; docs/mcap.md gives the layouts and topics).

Every message is plain CDR with the 4-byte encapsulation header ``00 01 00 00`` (CDR_LE);
alignment counts from after it. Only definitions ROS 2's own packages ship are used
(``can_msgs``, ``geometry_msgs``, ``sensor_msgs``, ``std_msgs``, ``tf2_msgs``), and for CAN FD
frames ``ros2_socketcan_msgs/msg/FdFrame``, the message ROS 2's SocketCAN driver publishes.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skin.errors import ConfigError

CDR_LE = b"\x00\x01\x00\x00"


def require_mcap(field: str = "--record") -> Any:
    """The ``mcap`` package's writer module; ConfigError naming the extra when it is absent."""
    try:
        import mcap.writer
    except ImportError as err:
        raise ConfigError(field, "an .mcap recording needs the mcap package: pip install "
                          "'canskin[mcap]'") from err
    return mcap.writer

_TIME = "int32 sec\nuint32 nanosec\n"
_HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
_SEP = "=" * 80 + "\n"


def _with(main: str, *deps: tuple[str, str]) -> str:
    return main + "".join(f"{_SEP}MSG: {name}\n{text}" for name, text in deps)


_H = (("std_msgs/Header", _HEADER), ("builtin_interfaces/Time", _TIME))
_VECTOR3 = ("geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z\n")
_POINT_FIELD = ("sensor_msgs/PointField",
                "uint8 INT8=1\nuint8 UINT8=2\nuint8 INT16=3\nuint8 UINT16=4\nuint8 INT32=5\n"
                "uint8 UINT32=6\nuint8 FLOAT32=7\nuint8 FLOAT64=8\nstring name\nuint32 offset\n"
                "uint8 datatype\nuint32 count\n")
SCHEMAS: dict[str, str] = {
    "can_msgs/msg/Frame": _with(
        "std_msgs/Header header\nuint32 id\nbool is_rtr\nbool is_extended\nbool is_error\n"
        "uint8 dlc\nuint8[8] data\n", *_H),
    "ros2_socketcan_msgs/msg/FdFrame": _with(
        "std_msgs/Header header\nuint32 id\nbool is_extended\nbool is_error\nuint8 len\n"
        "uint8[] data\n", *_H),
    "sensor_msgs/msg/PointCloud2": _with(
        "std_msgs/Header header\nuint32 height\nuint32 width\nPointField[] fields\n"
        "bool is_bigendian\nuint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n",
        *_H, _POINT_FIELD),
    "geometry_msgs/msg/WrenchStamped": _with(
        "std_msgs/Header header\nWrench wrench\n", *_H,
        ("geometry_msgs/Wrench", "Vector3 force\nVector3 torque\n"), _VECTOR3),
    "geometry_msgs/msg/PointStamped": _with(
        "std_msgs/Header header\nPoint point\n", *_H,
        ("geometry_msgs/Point", "float64 x\nfloat64 y\nfloat64 z\n")),
    "std_msgs/msg/UInt8": "uint8 data\n",
    "tf2_msgs/msg/TFMessage": _with(
        "geometry_msgs/TransformStamped[] transforms\n",
        ("geometry_msgs/TransformStamped",
         "std_msgs/Header header\nstring child_frame_id\nTransform transform\n"), *_H,
        ("geometry_msgs/Transform", "Vector3 translation\nQuaternion rotation\n"), _VECTOR3,
        ("geometry_msgs/Quaternion", "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n")),
}
FRAME, FD_FRAME = "can_msgs/msg/Frame", "ros2_socketcan_msgs/msg/FdFrame"
TAXELS, WRENCH, POINT = "sensor_msgs/msg/PointCloud2", "geometry_msgs/msg/WrenchStamped", \
    "geometry_msgs/msg/PointStamped"
STATE, TF = "std_msgs/msg/UInt8", "tf2_msgs/msg/TFMessage"

FRAMES_TOPIC, FD_FRAMES_TOPIC, TF_STATIC_TOPIC = "/can/frames", "/can/fd_frames", "/tf_static"
SKIN_FRAME = "skin"


def patch_frame(patch: int) -> str:
    """The tf frame of a patch (its taxel positions, CoP, wrench are in it)."""
    return f"skin_patch_{patch}"


def patch_topic(patch: int, what: str) -> str:
    return f"/skin/patch_{patch}/{what}"


def stamp_ns(seconds: float) -> int:
    """``seconds`` in whole nanoseconds, rounded exactly (not through a float product)."""
    num, den = seconds.as_integer_ratio()
    return (2 * num * 1_000_000_000 + den) // (2 * den)


def seconds_of(ns: int) -> float:
    """The float nearest ``ns`` nanoseconds: ``seconds_of(stamp_ns(t)) == t`` for every t
    of 2**23 s (97 days) and more, as every wall-clock time is."""
    return ns / 1_000_000_000


def _stamp(ns: int) -> tuple[int, int]:
    sec, nsec = divmod(ns, 1_000_000_000)
    return sec, nsec


class _Cdr:
    """A CDR body being written: values aligned to their size from after the header."""

    def __init__(self) -> None:
        self.out = bytearray(CDR_LE)

    def align(self, size: int) -> None:
        self.out += b"\0" * (-(len(self.out) - 4) % size)

    def pack(self, fmt: str, size: int, *values: object) -> None:
        self.align(size)
        self.out += struct.pack("<" + fmt, *values)

    def string(self, text: str) -> None:
        raw = text.encode() + b"\0"
        self.pack("I", 4, len(raw))
        self.out += raw

    def header(self, ns: int, frame_id: str) -> None:
        self.pack("iI", 4, *_stamp(ns))
        self.string(frame_id)

    def blob(self, data: bytes) -> None:
        self.pack("I", 4, len(data))
        self.out += data


class FrameEncoder:
    """``can_msgs/msg/Frame`` of classic frames on one channel (``header.frame_id``)."""

    def __init__(self, channel: str) -> None:
        name = channel.encode() + b"\0"
        pad = -(8 + 4 + len(name)) % 4
        self._struct = struct.Struct(f"<4siII{len(name)}s{pad}xI4B8s")
        self._name = name

    def encode(self, ns: int, can_id: int, rtr: bool, extended: bool, error: bool, dlc: int,
               data: bytes) -> bytes:
        sec, nsec = divmod(ns, 1_000_000_000)
        return self._struct.pack(CDR_LE, sec, nsec, len(self._name), self._name, can_id, rtr,
                                 extended, error, dlc, data)


def encode_fd_frame(ns: int, channel: str, can_id: int, extended: bool, error: bool,
                    data: bytes) -> bytes:
    """``ros2_socketcan_msgs/msg/FdFrame``: ``len`` is the data length (0..64)."""
    cdr = _Cdr()
    cdr.header(ns, channel)
    cdr.pack("I??B", 4, can_id, extended, error, len(data))
    cdr.blob(data)
    return bytes(cdr.out)


@dataclass(frozen=True)
class DecodedFrame:
    ns: int
    channel: str
    can_id: int
    rtr: bool
    extended: bool
    error: bool
    fd: bool
    dlc: int
    data: bytes


def _read_header(raw: bytes) -> tuple[int, str, int]:
    """(stamp ns, frame_id, offset after it) of a message that starts with a Header."""
    if raw[:4] != CDR_LE:
        raise ValueError(f"not little-endian CDR (encapsulation {raw[:4].hex()})")
    sec, nsec, size = struct.unpack_from("<iII", raw, 4)
    if not 0 < size <= len(raw) - 16:
        raise ValueError(f"frame_id of {size} bytes in a {len(raw)}-byte message")
    end = 16 + size
    frame_id = raw[16:end - 1].decode()
    return sec * 1_000_000_000 + nsec, frame_id, end + (-(end - 4) % 4)


def decode_frame(raw: bytes, fd: bool) -> DecodedFrame:
    """A ``can_msgs/msg/Frame`` (``fd``: an ``FdFrame``); ValueError or struct.error if it
    is not one."""
    ns, channel, at = _read_header(raw)
    if fd:
        can_id, extended, error, length, size = struct.unpack_from("<I??BxI", raw, at)
        data = raw[at + 12:at + 12 + size]
        if size != len(data) or size != length:
            raise ValueError(f"FD frame of {length} bytes holds {len(data)}")
        return DecodedFrame(ns, channel, can_id, False, extended, error, True, length, data)
    can_id, rtr, extended, error, dlc, data8 = struct.unpack_from("<I???B8s", raw, at)
    if len(raw) != at + 16:
        raise ValueError(f"a can_msgs/msg/Frame is {at + 16} bytes, this one {len(raw)}")
    data = b"" if rtr else data8[:min(dlc, 8)]
    return DecodedFrame(ns, channel, can_id, rtr, extended, error, False, int(dlc), data)


# One taxel of a patch's PointCloud2: where it is (float32, for the 3D panel) and the
# sample's figures (float64 forces: exactly the host's). docs/mcap.md lists the fields.
TAXEL_DTYPE = np.dtype({
    "names": ["x", "y", "z", "valid", "reason", "contact", "slip", "fx", "fy", "fz",
              "time_s", "cycle", "sync_counter", "force_node", "flags", "patch"],
    "formats": ["<f4", "<f4", "<f4", "u1", "u1", "u1", "u1", "<f8", "<f8", "<f8", "<f8",
                "<u4", "u1", "u1", "u1", "u1"],
    "offsets": [0, 4, 8, 12, 13, 14, 15, 16, 24, 32, 40, 48, 52, 53, 54, 55],
    "itemsize": 56})
COMPLETE, PUBLISHED = 1, 2
_DATATYPE = {"<f4": 7, "<f8": 8, "|u1": 2, "<u4": 6}


def _fields_cdr() -> list[tuple[str, int, int]]:
    fields = TAXEL_DTYPE.fields
    assert fields is not None
    return [(name, int(fields[name][1]), _DATATYPE[fields[name][0].str])
            for name in TAXEL_DTYPE.names or ()]


_FIELDS = _fields_cdr()


def encode_taxels(ns: int, frame_id: str, points: NDArray[np.void]) -> bytes:
    """A ``sensor_msgs/msg/PointCloud2`` of one sample: ``points`` of :data:`TAXEL_DTYPE`."""
    cdr = _Cdr()
    cdr.header(ns, frame_id)
    cdr.pack("II", 4, 1, len(points))
    cdr.pack("I", 4, len(_FIELDS))
    for name, offset, datatype in _FIELDS:
        cdr.string(name)
        cdr.pack("IB", 4, offset, datatype)
        cdr.pack("I", 4, 1)
    cdr.pack("?", 1, False)
    cdr.pack("II", 4, TAXEL_DTYPE.itemsize, TAXEL_DTYPE.itemsize * len(points))
    cdr.blob(points.tobytes())
    cdr.pack("?", 1, True)
    return bytes(cdr.out)


def decode_taxels(raw: bytes) -> tuple[int, str, NDArray[np.void]]:
    """(stamp ns, frame_id, points) of :func:`encode_taxels`' message; ValueError else."""
    ns, frame_id, at = _read_header(raw)
    height, width, count = struct.unpack_from("<III", raw, at)
    at += 12
    fields = []
    for _ in range(count):
        (size,) = struct.unpack_from("<I", raw, at)
        name = raw[at + 4:at + 3 + size].decode()
        at += 4 + size
        at += -(at - 4) % 4
        offset, datatype = struct.unpack_from("<IB", raw, at)
        at += 12
        fields.append((name, offset, datatype))
    if fields != _FIELDS:
        raise ValueError("not canskin's taxel fields")
    _big, step, _row = struct.unpack_from("<?xxxII", raw, at)
    (size,) = struct.unpack_from("<I", raw, at + 12)
    data = raw[at + 16:at + 16 + size]
    if step != TAXEL_DTYPE.itemsize or len(data) != size or size != step * height * width:
        raise ValueError(f"{size} bytes of points, {height} x {width} of {step} expected")
    return ns, frame_id, np.frombuffer(data, dtype=TAXEL_DTYPE)


def encode_wrench(ns: int, frame_id: str, force: NDArray[np.float64],
                  torque: NDArray[np.float64]) -> bytes:
    cdr = _Cdr()
    cdr.header(ns, frame_id)
    cdr.pack("6d", 8, *force.tolist(), *torque.tolist())
    return bytes(cdr.out)


def encode_point(ns: int, frame_id: str, x: float, y: float, z: float) -> bytes:
    cdr = _Cdr()
    cdr.header(ns, frame_id)
    cdr.pack("3d", 8, x, y, z)
    return bytes(cdr.out)


def encode_uint8(value: int) -> bytes:
    return CDR_LE + bytes((value,))


@dataclass(frozen=True)
class Placement:
    """Where a patch sits on the skin: the host config's ``position_m``, ``orientation_deg``
    (about the skin's normal, z) and the taxel pitch."""

    patch: int
    position_m: tuple[float, float]
    orientation_deg: float
    pitch_m: float


def encode_tf_static(ns: int, placements: list[Placement]) -> bytes:
    """``tf2_msgs/msg/TFMessage``: each patch's frame in the ``skin`` frame."""
    cdr = _Cdr()
    cdr.pack("I", 4, len(placements))
    for place in placements:
        half = math.radians(place.orientation_deg) / 2
        cdr.header(ns, SKIN_FRAME)
        cdr.string(patch_frame(place.patch))
        cdr.pack("7d", 8, *place.position_m, 0.0, 0.0, 0.0, math.sin(half), math.cos(half))
    return bytes(cdr.out)
