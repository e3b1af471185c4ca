from __future__ import annotations

import functools
import sys
from importlib import resources
from pathlib import Path

import canopen
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from canbus import codes
from canbus.od import SHIPPED, eds_file, load_od
from canbus.pdo_codec import PdoCodec, read_defaults, read_layouts
from canbus.tools.edscheck import check
from skin.errors import ConfigError
from tests.support.rigs import children

FILES = Path(__file__).parents[1] / "files"


@pytest.mark.parametrize("name", ["skin-patch", "skin-forces"])
def test_shipped_eds_pass_check_and_load(name: str) -> None:
    with eds_file(name) as path:
        assert check(path) == []
    od = load_od(name, 3)
    assert od[0x1800][1].default == 0x183


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_eds_found_by_name_in_the_installed_eds_package(name: str) -> None:
    import eds  # the package the wheel ships the EDS files in

    resource = resources.files(eds).joinpath(f"{name}.eds")
    assert resource.is_file()
    with eds_file(name) as by_name, eds_file(f"{name}.eds") as with_suffix:
        assert by_name == with_suffix == Path(str(resource))
        assert by_name.parent == Path(eds.__file__).parent
    with resources.as_file(resource) as path:
        od = canopen.import_od(str(path), 5)
    assert od[0x1018][2].default == (1 if name == "skin-patch" else 2)  # product code
    assert od[0x1014].default == 0x85 and load_od(name, 5)[0x1014].default == 0x85


def test_unknown_eds_name_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="no shipped EDS 'skin-nothing'"):
        load_od("skin-nothing", 1)


@pytest.mark.parametrize(("file", "message"), [
    ("broken-list-count", "[MandatoryObjects] SupportedObjects=4 but lists 3 objects"),
    ("broken-missing-mandatory", "mandatory object 0x1018 is missing"),
    ("broken-datatype", "[1017] DataType '0x0099' is not a CiA 301 basic data type"),
    ("broken-accesstype", "[1017] AccessType 'readwrite' is not one of"),
    ("broken-unmappable", "[1A00sub1] maps 0x1017:00, which is not PDO-mappable"),
    ("broken-size", "[1A00sub1] maps 8 bits of 0x2000:01, which has 16"),
    ("broken-missing-target", "[1A00sub1] maps 0x3000:01, which does not exist"),
    ("broken-64-bits", "[1A00] maps 80 bits, more than the 64 a PDO holds"),
])
def test_broken_eds_fail_with_their_message(file: str, message: str) -> None:
    problems = check(FILES / f"{file}.eds")
    assert any(p.startswith(message) for p in problems), problems


def test_eds_check_cli_exit_codes() -> None:
    cmd = [sys.executable, "-m", "skin.cli", "eds", "check"]
    ok = children.run([*cmd, "skin-patch", "skin-forces"], timeout=120)
    assert ok.returncode == 0, ok.stderr
    bad = children.run([*cmd, str(FILES / "broken-size.eds")], timeout=120)
    assert bad.returncode == 1
    assert bad.stderr.count("\n") == 1 and "maps 8 bits" in bad.stderr


@functools.cache
def _codec(name: str) -> PdoCodec:
    """Built once: the round trips below run it on every Hypothesis example."""
    od = load_od(name, 1)
    return PdoCodec(read_layouts(read_defaults(od), 7), od)


def test_default_mapping_is_27_values_in_7_pdos() -> None:
    codec = _codec("skin-patch")
    assert [layout.size for layout in codec.layouts] == [8] * 6 + [6]
    assert codec.variables == tuple((0x2000, k) for k in range(1, 28))
    assert codec.cob_ids.tolist() == [0x181, 0x281, 0x381, 0x481, 0x201, 0x301, 0x401]


@given(hnp.arrays(np.uint16, st.tuples(st.integers(1, 5), st.just(27))))
def test_patch_codec_round_trip(values: np.ndarray) -> None:
    codec = _codec("skin-patch")
    payloads = codec.pack(values)
    assert payloads.shape == (len(values), 7, 8)
    assert payloads[0, 0, :2].tobytes() == int(values[0, 0]).to_bytes(2, "little")
    np.testing.assert_array_equal(codec.unpack(payloads), values)


@given(hnp.arrays(np.int16, st.tuples(st.integers(1, 5), st.just(27))),
       hnp.arrays(np.uint16, st.tuples(st.just(1), st.just(1))))
def test_forces_codec_round_trip_is_signed(forces: np.ndarray, valid_bits: np.ndarray) -> None:
    codec = _codec("skin-forces")  # 27 INTEGER16 forces, then 0x2005 (UNSIGNED16) in TPDO 7
    assert codec.variables[-1] == (0x2005, 0)
    values = np.hstack([forces.astype(np.int64), valid_bits.repeat(len(forces), axis=0)])
    np.testing.assert_array_equal(codec.unpack(codec.pack(values)), values)


def test_codec_matches_canopen_pdo_decoding() -> None:
    codec = _codec("skin-patch")
    values = np.arange(1000, 1027, dtype=np.uint16)[None, :]
    payload = codec.pack(values)[0, 1, :8].tobytes()
    node = canopen.Network().add_node(canopen.RemoteNode(1, load_od("skin-patch", 1)))
    node.tpdo.read(from_od=True)
    node.tpdo[2].on_message(0x281, bytearray(payload), 0.0)
    assert [v.raw for v in node.tpdo[2].map] == [1004, 1005, 1006, 1007]


def test_codes_reserve_fault_values() -> None:
    r = np.array([[np.inf, 0.0, 1e9], [1000.0, 1000.02, -1.0]])
    c = codes.resistance_to_code(r, 0.05)
    assert c.tolist() == [[codes.OPEN, codes.SHORT, codes.SATURATED], [20000, 20000, codes.SHORT]]
    status = codes.taxel_status(c.reshape(2, 1, 3).repeat(9, axis=1), 3)
    assert status[0, 0] == 1 | 2 << 2 | 3 << 4 and status[1, 0] == 2 << 4


