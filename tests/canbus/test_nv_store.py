"""Settings that survive power-off: 0x1010/0x1011 with CiA 301's signatures, the state
file of a simulated patch (atomic, refused in one line when corrupt or foreign), and
``skin sim run --state-dir``."""

from __future__ import annotations

import json
import struct
import threading
from collections.abc import Iterator
from pathlib import Path

import canopen
import pytest
from canopen.sdo.exceptions import SdoAbortedError
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from canbus.device.nv_store import NvStore, NvStoreError
from canbus.device.patch_node import PatchNode
from canbus.device.patch_server import PatchServer
from canbus.identity import Identity
from canbus.master.forcenode import ForceNode
from canbus.od import load_od
from skin.cli import main
from tests.support.rigs.host import Rest

SAVE, LOAD = b"save", b"load"
ID = Identity(0, 1, 0x0001_0000, 0x1234)


class Pair:
    """A patch server (one patch, node 1) whose state lives in ``folder``, and a master."""

    def __init__(self, channel: str, folder: Path) -> None:
        self.device = canopen.Network()
        self.device.NOTIFIER_CYCLE = 0.05
        self.device.connect(interface="virtual", channel=channel)
        self.master = canopen.Network()
        self.master.NOTIFIER_CYCLE = 0.05
        self.master.connect(interface="virtual", channel=channel)
        self.server = PatchServer(self.device, Rest(1), serials=[0x1234],
                                  nv=lambda i: NvStore.in_dir(folder, "patch", i))
        self.server.start()
        self.node = self.master.add_node(canopen.RemoteNode(1, load_od("skin-patch", 1)))
        self.node.sdo.RESPONSE_TIMEOUT = 2.0

    def reset(self, command: int) -> None:
        """NMT reset node (0x81) or communication (0x82), then its boot-up (waited for)."""
        booted = threading.Event()

        def on_boot(cob_id: int, data: bytearray, timestamp: float) -> None:
            if bytes(data) == b"\x00":
                booted.set()

        self.master.subscribe(0x701, on_boot)
        try:
            self.node.nmt.send_command(command)
            assert booted.wait(10.0), "no boot-up after the reset"
        finally:
            self.master.unsubscribe(0x701, on_boot)

    def close(self) -> None:
        self.server.stop()
        self.master.disconnect()
        self.device.disconnect()


@pytest.fixture
def pair(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Pair]:
    p = Pair(request.node.name, tmp_path)
    yield p
    p.close()


def _restart(pair: Pair, request: pytest.FixtureRequest, folder: Path) -> Pair:
    pair.close()
    return Pair(request.node.name + "-again", folder)


def test_save_keeps_written_values_across_a_restart_and_load_brings_defaults_back(
        pair: Pair, request: pytest.FixtureRequest, tmp_path: Path) -> None:
    sdo = pair.node.sdo
    assert sdo.upload(0x1010, 1) == b"\x01\x00\x00\x00"  # saves on command
    sdo.download(0x1017, 0, struct.pack("<H", 250))
    sdo.download(0x2002, 5, struct.pack("<I", 1_500_000))  # R0 1500 ohm, in mOhm
    with pytest.raises(SdoAbortedError) as err:
        sdo.download(0x1010, 1, b"evas")  # the signature backwards
    assert err.value.code == 0x0800_0020
    sdo.download(0x1010, 2, SAVE)  # communication parameters only
    assert sdo.upload(0x1010, 2) == b"\x01\x00\x00\x00"
    stored = json.loads((tmp_path / "patch-00001234.json").read_text())
    assert stored["objects"] == {"1017:00": "fa00"}
    sdo.download(0x1010, 4, SAVE)  # and the manufacturer's: R0
    pair = _restart(pair, request, tmp_path)
    try:
        sdo = pair.node.sdo
        assert sdo.upload(0x1017, 0) == struct.pack("<H", 250)
        assert sdo.upload(0x2002, 5) == struct.pack("<I", 1_500_000)
        assert pair.server.nodes[0].heartbeat.period_ms == 250
        sdo.download(0x1011, 1, LOAD)  # restore all defaults: from the next reset on
        assert sdo.upload(0x1017, 0) == struct.pack("<H", 250)
        pair.reset(0x81)  # reset node
        assert sdo.upload(0x1017, 0) == struct.pack("<H", 1000)
        assert sdo.upload(0x2002, 5) == struct.pack("<I", 1_414_214)
    finally:
        pair.close()


def test_an_unsaved_value_is_lost_at_reset_a_saved_one_is_not(pair: Pair) -> None:
    sdo = pair.node.sdo
    sdo.download(0x1017, 0, struct.pack("<H", 300))
    sdo.download(0x1010, 1, SAVE)
    sdo.download(0x1017, 0, struct.pack("<H", 400))  # not saved
    pair.reset(0x82)  # reset communication
    assert sdo.upload(0x1017, 0) == struct.pack("<H", 300)


def test_force_nodes_save_their_parameters(tmp_path: Path) -> None:
    nv = NvStore.in_dir(tmp_path, "forces", Identity(0, 2, 0x0001_0000, 65))
    node = ForceNode(65, 1, nv=nv)
    node.store.set_data(0x2001, 0, b"\x07", check_writable=True)
    node.store.set_data(0x1010, 1, SAVE, check_writable=True)
    again = ForceNode(65, 1, nv=NvStore.in_dir(tmp_path, "forces", nv.identity))
    assert again.store.value(0x2001) == 7
    assert 0x2007 not in {i for i, _ in again.nv.content.objects}  # a command, not stored


# --- the state file ---------------------------------------------------------------------

def _write(path: Path, doc: object) -> None:
    path.write_text(json.dumps(doc))


GOOD = {"format": "canskin-nv-store", "version": 1,
        "identity": {"vendor": 0, "product": 1, "revision": 65536, "serial": 0x1234},
        "lss": {"node_id": 5, "bit_timing": 0}, "objects": {"1017:00": "6400"}}


def test_a_good_state_file_round_trips(tmp_path: Path) -> None:
    path = tmp_path / "s.json"
    _write(path, GOOD)
    store = NvStore(path, ID)
    assert store.content.node_id == 5 and store.content.objects == {(0x1017, 0): b"\x64\x00"}
    store.save_objects({(0x2002, 1): b"\x01\x02\x03\x04"}, 0x2000, 0x5FFF)
    assert NvStore(path, ID).content.objects == {(0x1017, 0): b"\x64\x00",
                                                 (0x2002, 1): b"\x01\x02\x03\x04"}
    assert [p.name for p in tmp_path.iterdir()] == ["s.json"]  # no temp file left


@pytest.mark.parametrize(("doc", "field"), [
    ({**GOOD, "format": "other"}, "format"),
    ({**GOOD, "version": 2}, "version"),
    ({**GOOD, "identity": {**GOOD["identity"], "serial": 0x9999}}, "identity.serial"),  # type: ignore[dict-item]
    ({**GOOD, "lss": {"node_id": 0}}, "lss.node_id"),
    ({**GOOD, "lss": {"node_id": 5, "bit_timing": 5}}, "lss.bit_timing"),
    ({**GOOD, "objects": {"1017": "00"}}, "objects.1017"),
    ({**GOOD, "objects": {"1017:00": "zz"}}, "objects.1017:00"),
    ([1, 2], "format"),
])
def test_a_foreign_or_broken_state_file_is_refused_naming_the_field(
        tmp_path: Path, doc: object, field: str) -> None:
    path = tmp_path / "s.json"
    _write(path, doc)
    with pytest.raises(NvStoreError) as err:
        NvStore(path, ID)
    assert err.value.field == f"{path}.{field}"
    assert "\n" not in str(err.value)


def test_a_stored_object_the_device_cannot_take_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "patch-00001234.json"
    for objects, why in (({"1000:00": "00000000"}, "no such writable parameter"),
                         ({"1017:00": "01"}, "0x06070013"),  # one byte of an UNSIGNED16
                         ({"2002:01": "00000000"}, "0x06090032")):  # R0 0: below LowLimit
        _write(path, {**GOOD, "objects": objects})
        with pytest.raises(NvStoreError, match=why):
            PatchNode(1, serial=0x1234, nv=NvStore(path, ID))


@settings(max_examples=80, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.one_of(st.binary(max_size=200),
                 st.recursive(st.none() | st.booleans() | st.integers() | st.text(max_size=8),
                              lambda inner: st.lists(inner, max_size=4) |
                              st.dictionaries(st.sampled_from([*GOOD, "x"]), inner,
                                              max_size=6), max_leaves=12)
                 .map(lambda doc: json.dumps(doc).encode())))
def test_any_state_file_is_read_or_refused_in_one_line(tmp_path: Path, raw: bytes) -> None:
    path = tmp_path / "s.json"
    path.write_bytes(raw)
    message = ""
    try:
        store = NvStore(path, ID)
    except NvStoreError as err:
        message = str(err)
    if message:
        assert message.startswith(str(path)) and "\n" not in message
    else:
        assert store.content.node_id in (None, *range(1, 128), 0xFF)


def test_skin_sim_run_refuses_a_corrupt_state_file_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        request: pytest.FixtureRequest) -> None:
    (tmp_path / "patch-00000001.json").write_text("{not json")
    code = main(["sim", "run", "idle", "--patches", "2", "--state-dir", str(tmp_path),
                 "--seconds", "0.2", "-i", "virtual", "-c", request.node.name])
    err = capsys.readouterr().err
    assert code != 0 and err.count("\n") == 1 and "patch-00000001.json" in err
    assert "Traceback" not in err


def test_the_host_config_names_serials_lss_and_the_state_dir(tmp_path: Path) -> None:
    from canbus.master.hostconfig import host_config_from_dict
    from canbus.master.lss_assign import force_node_store
    from skin.errors import ConfigError

    config = host_config_from_dict({"host": {"lss": "auto", "lss_store": True,
                                             "state_dir": "state"},
                                    "patches": [{"node_id": 1, "serial": 0x1001},
                                                {"node_id": 2}]}, base=tmp_path)
    assert config.lss == "auto" and config.lss_store
    assert config.patches[0].serial == 0x1001 and config.patches[1].serial is None
    assert config.state_dir == str(tmp_path / "state")
    store = force_node_store(config.state_dir, 65)
    assert store is not None and store.path == tmp_path / "state" / "forces-00000041.json"
    for doc, field in (
            ({"host": {"lss": "sometimes"}, "patches": [{"node_id": 1}]}, "host.lss"),
            ({"patches": [{"node_id": 1, "serial": -1}]}, "patches[0].serial"),
            ({"patches": [{"node_id": 1, "serial": 7}, {"node_id": 2, "serial": 7}]},
             "patches[1].serial"),
            ({"patches": [{"node_id": 1, "serial": "7"}]}, "patches[0].serial")):
        with pytest.raises(ConfigError) as err:
            host_config_from_dict(doc)
        assert err.value.field == field


def test_a_saved_pdo_mapping_and_an_lss_bit_timing_survive_a_restart(
        pair: Pair, request: pytest.FixtureRequest, tmp_path: Path) -> None:
    sdo = pair.node.sdo
    sdo.download(0x1800, 1, struct.pack("<I", 0x8000_0181))  # CiA 301 remap sequence
    sdo.download(0x1A00, 0, b"\x00")
    sdo.download(0x1A00, 1, struct.pack("<I", 0x2004_0108))
    sdo.download(0x1A00, 2, struct.pack("<I", 0x2004_0208))
    sdo.download(0x1A00, 0, b"\x02")
    sdo.download(0x1800, 1, struct.pack("<I", 0x181))
    sdo.download(0x1010, 2, SAVE)
    lss = pair.master.lss  # bit timing 3 (250 kbit/s), stored by LSS
    assert lss.send_switch_state_selective(0, 1, 0x0001_0000, 0x1234)
    lss.configure_bit_timing(3)
    lss.store_configuration()
    lss.send_switch_state_global(lss.WAITING_STATE)
    pair = _restart(pair, request, tmp_path)
    try:
        patch = pair.server.nodes[0]
        assert [(e.index, e.subindex) for e in patch.tpdo.codec.layouts[0].entries] == \
            [(0x2004, 1), (0x2004, 2)]
        assert pair.node.sdo.upload(0x1A00, 0) == b"\x02"
        assert patch.lss is not None and patch.lss.bit_timing == 3
        assert patch.node_id == 1  # stored with it: the node-ID it had
    finally:
        pair.close()
