"""Recordings (.log, .asc, .blf, .pcap) damaged on purpose: the replay stops at the first
bad frame with one line naming the file and the frame; a BLF object of size 0 ends, a
BLF container that inflates without bound is refused."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import pytest
from can.io import blf
from hypothesis import given
from hypothesis import strategies as st

from tests.inputs.blf_files import blf_file, can_objects
from tests.inputs.conftest import examples
from tests.inputs.hostile import answered, fingerprint, mutate_bytes, refused, run

RECORDINGS = Path(__file__).resolve().parents[1] / "files" / "recordings"
GOOD = sorted(RECORDINGS.glob("good.*"))


def _replay(path: Path) -> None:
    folder = path.parent
    before = fingerprint(folder)
    result = run("replay", path, "--fast", "-i", "virtual", "-c", f"hostile{id(path)}")
    answered(result)
    if result.code:
        assert str(path) in result.lines[0]
    assert fingerprint(folder) == before


@examples(60)
@given(data=st.data(), source=st.sampled_from(GOOD))
def test_a_recording_damaged_in_its_bytes(tmp_path_factory: pytest.TempPathFactory,
                                          data: st.DataObject, source: Path) -> None:
    path = tmp_path_factory.mktemp("recording") / source.name
    path.write_bytes(mutate_bytes(source.read_bytes(), data.draw))
    _replay(path)


@examples(40)
@given(data=st.data())
def test_a_blf_object_of_any_declared_size(tmp_path_factory: pytest.TempPathFactory,
                                           data: st.DataObject) -> None:
    inner = bytearray(can_objects(3))
    at = data.draw(st.sampled_from((0, 48, 96)))  # an object's header in the container
    struct.pack_into("<L", inner, at + 8, data.draw(st.sampled_from(
        (0, 1, 15, 16, 31, 2**31 - 1, 2**32 - 1, 40, 48, 47))))
    path = tmp_path_factory.mktemp("blf") / "r.blf"
    path.write_bytes(blf_file(bytes(inner)))
    _replay(path)


@pytest.mark.parametrize(("declared", "inflated"), [(1 << 30, 1 << 24), (1000, 1 << 26)])
def test_a_blf_decompression_bomb_is_refused(tmp_path: Path, declared: int,
                                             inflated: int) -> None:
    zeros = zlib.compressobj(9)
    packed = b"".join(zeros.compress(bytes(1 << 24)) for _ in range(inflated >> 24))
    packed += zeros.flush()
    path = tmp_path / "bomb.blf"
    data = bytearray(blf_file(b"", declared))
    body_at = 144 + blf.OBJ_HEADER_BASE_STRUCT.size + blf.LOG_CONTAINER_STRUCT.size
    data = data[:body_at] + packed
    size = len(data) - 144
    struct.pack_into("<L", data, 144 + 8, size)
    header = list(blf.FILE_HEADER_STRUCT.unpack_from(data, 0))
    header[10] = len(data) + size % 4
    data[:blf.FILE_HEADER_STRUCT.size] = blf.FILE_HEADER_STRUCT.pack(*header)
    path.write_bytes(bytes(data) + bytes(size % 4))
    result = run("replay", path, "--fast", "-i", "virtual", "-c", "bomb")
    refused(result)
    assert "container" in result.lines[0] and str(path) in result.lines[0]
