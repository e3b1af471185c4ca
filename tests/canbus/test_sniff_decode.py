"""Services in words: scripted byte traces decoded exactly, SDO-followed PDO mappings, filters."""

from __future__ import annotations

import can
import pytest

from canbus.tools.attribution import Attribution, KnownNode
from canbus.tools.pdo_dictionary import Dictionary, parse_assignment
from canbus.tools.pdo_names import shipped_default
from canbus.tools.services import Service, ServiceDecoder, route
from canbus.tools.sniffer import FrameFilter
from skin.errors import ConfigError


def _msg(cob_id: int, data: str, *, extended: bool = False) -> can.Message:
    return can.Message(arbitration_id=cob_id, data=bytes.fromhex(data), is_extended_id=extended,
                       timestamp=1.0)


TRACE = [  # (COB-ID, payload, service, node label, label, text)
    (0x000, "0100", "nmt", "", "NMT", "start all nodes"),
    (0x000, "8103", "nmt", "", "NMT", "reset node node 3"),
    (0x080, "", "sync", "", "SYNC", "SYNC"),
    (0x080, "05", "sync", "", "SYNC", "SYNC counter 5"),
    (0x701, "00", "heartbeat", "patch 1", "heartbeat", "boot-up"),
    (0x701, "7f", "heartbeat", "patch 1", "heartbeat", "pre-operational"),
    (0x742, "05", "heartbeat", "forces 66", "heartbeat", "operational"),
    (0x601, "4018100200000000", "sdo", "patch 1", "SDO rx",
     "read 0x1018:02 Identity object.Product code"),
    (0x581, "4318100201000000", "sdo", "patch 1", "SDO tx",
     "0x1018:02 Identity object.Product code = 0x00000001"),
    (0x601, "2b17100032000000", "sdo", "patch 1", "SDO rx",
     "write 0x1017:00 Producer heartbeat time = 50 ms"),
    (0x581, "6017100000000000", "sdo", "patch 1", "SDO tx",
     "write 0x1017:00 Producer heartbeat time done"),
    (0x601, "4001200000000000", "sdo", "patch 1", "SDO rx",
     "read 0x2001:00 Resistance LSB (uOhm)"),
    (0x581, "4301200050c30000", "sdo", "patch 1", "SDO tx",
     "0x2001:00 Resistance LSB (uOhm) = 0.05 Ω"),
    (0x581, "8000201c11000906", "sdo", "patch 1", "SDO tx",
     "abort 0x2000:1C: Code 0x06090011, Subindex does not exist"),
    (0x581, "0000000000000000", "sdo", "patch 1", "SDO tx", "upload segment, toggle 0"),
    (0x605, "2f001a0000000000", "sdo", "patch 5", "SDO rx",
     "write 0x1A00:00 TPDO 1 mapping parameter.Number of mapped application objects in PDO "
     "= 0"),
    (0x585, "6000180100000000", "sdo", "patch 5", "SDO tx",
     "write 0x1800:01 TPDO 1 communication parameter.COB-ID used by TPDO accepted"),
    (0x081, "0050810401000000", "emcy", "patch 1", "EMCY",
     "0x5000 Device Hardware, ER 0x81, data 04 01 00 00 00 (taxel 4: z open)"),
    (0x081, "0000000400000000", "emcy", "patch 1", "EMCY",
     "0x0000 Error Reset / No Error, ER 0x00, data 04 00 00 00 00 (taxel 4: ok)"),
    (0x181, "204e7c6effff0000", "pdo", "patch 1", "TPDO1",
     "R0z=1000.00 Ω R0x=1414.20 Ω R0y=open R1z=short"),
    (0x401, "204efeff7c6e", "pdo", "patch 1", "TPDO7",
     "R8z=1000.00 Ω R8x=saturated R8y=1414.20 Ω"),
    (0x1C1, "e80318fc0080e803", "pdo", "forces 65", "TPDO1",
     "F0x=+1.000 N F0y=-1.000 N F0z=none F1x=+1.000 N"),
    (0x441, "0000000088130f80", "pdo", "forces 65", "TPDO7",
     "F8x=+0.000 N F8y=+0.000 N F8z=+5.000 N valid=4/9"),
    (0x281, "0102", "pdo", "patch 1", "TPDO2",
     "01 02 (length 2, mapping needs 8)"),
    (0x100, "00000000 0100".replace(" ", ""), "time", "", "TIME",
     "TIME 1984-01-02T00:00:00.000+00:00"),
    (0x123, "01", "unknown", "", "0x123", "01"),
    (0x601, "2310100173617665", "sdo", "patch 1", "SDO rx",
     "write 0x1010:01 Store parameters.Save all parameters = 0x65766173"),
    (0x601, "4003100100000000", "sdo", "patch 1", "SDO rx",
     "read 0x1003:01 Pre-defined error field.Standard error field 1"),
    (0x581, "4303100100500407", "sdo", "patch 1", "SDO tx",
     "0x1003:01 Pre-defined error field.Standard error field 1 = 0x07045000"),
    (0x581, "4f29100102000000", "sdo", "patch 1", "SDO tx",
     "0x1029:01 Error behavior.Communication error = 2"),
    (0x581, "4302200546941500", "sdo", "patch 1", "SDO tx",
     "0x2002:05 Nominal resistances R0.Taxel 1 pillar x (mOhm) = 1414.214 Ω"),
    (0x581, "43032001404b4c00", "sdo", "patch 1", "SDO tx",
     "0x2003:01 Sensor constants.Youngs modulus (Pa) = 5000000 Pa"),
    (0x7E5, "4301100000000000", "lss", "", "LSS master",
     "switch state selective serial 0x00001001"),
    (0x7E4, "4400000000000000", "lss", "", "LSS slave",
     "switch state selective: the slave is in configuration state"),
    (0x1C2, "e80318fc0080e803", "pdo", "", "unattributed", "e8 03 18 fc 00 80 e8 03"),
]


def _told(*nodes: tuple[int, str]) -> ServiceDecoder:
    """A decoder told (as a host config tells it) that ``nodes`` keep their defaults."""
    return ServiceDecoder(attribution=Attribution(Dictionary(),
                                                  [KnownNode(n, eds) for n, eds in nodes]))


def test_trace_in_words() -> None:
    decoder = _told((1, "skin-patch"), (5, "skin-patch"), (65, "skin-forces"))
    got = []
    for cob_id, data, *_ in TRACE:
        decoded = decoder.decode(_msg(cob_id, data))
        got.append((cob_id, data, str(decoded.service), decoder.node_label(decoded.node),
                    decoded.label, decoded.text))
    assert got == TRACE


def test_segmented_upload_names_its_object() -> None:
    decoder = ServiceDecoder()
    texts = [decoder.decode(_msg(cob, data)).text for cob, data in [
        (0x605, "4018100000000000"),  # read 0x1018:00 ... as if segmented (a VISIBLE_STRING would)
        (0x585, "4118100009000000"),  # 9 bytes follow
        (0x605, "6000000000000000"),
        (0x585, "00736b696e2d7061"),  # 7 bytes, toggle 0
        (0x605, "7000000000000000"),
        (0x585, "1b7463000000000000"[:16]),  # toggle 1, n=5 (2 bytes), last
    ]]
    assert texts == [
        "read 0x1018:00 Identity object.Highest sub-index supported",
        "0x1018:00 Identity object.Highest sub-index supported: 9 bytes follow in segments",
        "upload segment request of 0x1018:00 Identity object.Highest sub-index supported, "
        "toggle 0",
        "upload segment, toggle 0, 7 bytes so far",
        "upload segment request of 0x1018:00 Identity object.Highest sub-index supported, "
        "toggle 1",
        "0x1018:00 Identity object.Highest sub-index supported = 115",  # U8: the first byte
    ]


def test_pdo_mapping_follows_sdo() -> None:
    """A master that remaps TPDO1 of patch 5 to pillar z of taxels 0..2 (the z-only mapping)."""
    decoder = ServiceDecoder()
    unknown = decoder.decode(_msg(0x185, "204e204e204e"))  # nothing says patch 5 sends it
    assert (unknown.node, unknown.label, unknown.text) == (None, "unattributed",
                                                           "20 4e 20 4e 20 4e")
    writes = [("1800", "01", "85010080"), ("1A00", "00", "00"), ("1A00", "01", "10010020"),
              ("1A00", "02", "10040020"), ("1A00", "03", "10070020"), ("1A00", "00", "03"),
              ("1800", "01", "85010000")]
    for index, sub, value in writes:
        size = len(value) // 2
        command = f"{0x23 | ((4 - size) << 2):02x}"
        index_le = index[2:] + index[:2]
        decoder.decode(_msg(0x605, command + index_le + sub + value.ljust(8, "0")))
        decoder.decode(_msg(0x585, "60" + index_le + sub + "00000000"))
    decoded = decoder.decode(_msg(0x185, "204e6e4e204e"))  # its COB-ID, written by SDO
    assert (decoded.node, decoded.label) == (5, "TPDO1")
    assert decoded.text == "R0z=1000.00 Ω R1z=1003.90 Ω R2z=1000.00 Ω"
    # an aborted write changes nothing
    decoder.decode(_msg(0x605, "2f001a0000000000"))
    decoder.decode(_msg(0x585, "80001a0000000106"))
    assert decoder.decode(_msg(0x185, "204e6e4e204e")).text == decoded.text
    # the LSB read back by SDO rescales the resistances
    decoder.decode(_msg(0x605, "4001200000000000"))
    decoder.decode(_msg(0x585, "4301200010270000"))  # 10000 uOhm = 0.01 ohm
    assert decoder.decode(_msg(0x185, "204e6e4e204e")).text == \
        "R0z=200.00 Ω R1z=200.78 Ω R2z=200.00 Ω"


def test_identity_read_switches_the_eds() -> None:
    decoder = ServiceDecoder()
    assert decoder.node_label(70) == "forces 70"
    decoder.decode(_msg(0x646, "4018100200000000"))
    decoder.decode(_msg(0x5C6, "4318100201000000"))  # product 1: a patch at node 70
    assert decoder.node_label(70) == "patch 70"
    decoder.decode(_msg(0x646, "4000180100000000"))
    decoder.decode(_msg(0x5C6, "43001801c6010000"))  # its TPDO 1 is on 0x1C6, read by SDO
    assert decoder.decode(_msg(0x1C6, "204e7c6e7c6e204e")).text.startswith("R0z=1000.00 Ω")


def test_routes() -> None:
    assert route(_msg(0x080, "")).service is Service.SYNC
    assert route(_msg(0x0FF, "")).node == 127
    assert route(_msg(0x7E5, "")).label == "LSS master"
    assert route(_msg(0x080, "", extended=True)).service is Service.UNKNOWN
    assert route(can.Message(is_error_frame=True)).service is Service.ERROR
    assert route(_msg(0x700, "")).service is Service.UNKNOWN  # node 0 is no node
    assert [route(_msg(c, "")).label for c in (0x185, 0x205, 0x285, 0x305, 0x385, 0x405,
                                              0x485, 0x505)] == \
        ["TPDO1", "RPDO1", "TPDO2", "RPDO2", "TPDO3", "RPDO3", "TPDO4", "RPDO4"]


def test_eds_assignments() -> None:
    assert [shipped_default(n) for n in (1, 64, 65, 127)] == \
        ["skin-patch", "skin-patch", "skin-forces", "skin-forces"]
    assert parse_assignment("3-5=skin-forces") == dict.fromkeys((3, 4, 5), "skin-forces")
    decoder = ServiceDecoder(Dictionary(parse_assignment("3=skin-forces")))
    assert decoder.node_label(3) == "forces 3"
    for bad, problem in [("3", "expected NODE=FILE"), ("x=skin-patch", "not a node-ID"),
                         ("0=skin-patch", "1..127"), ("5-2=skin-patch", "1..127"),
                         ("3=no-such.eds", "no shipped EDS")]:
        with pytest.raises(ConfigError, match=problem):
            parse_assignment(bad)


def test_frame_filter() -> None:
    by_node = FrameFilter(nodes=[1])
    assert by_node(route(_msg(0x181, ""))) and not by_node(route(_msg(0x182, "")))
    assert not by_node(route(_msg(0x080, "")))  # SYNC has no node
    by_service = FrameFilter(services=["sdo", "emcy"])
    assert by_service(route(_msg(0x581, ""))) and by_service(route(_msg(0x081, "")))
    assert not by_service(route(_msg(0x181, "")))
    assert FrameFilter()(route(_msg(0x123, "")))


def test_nodes_sharing_an_eds_keep_their_own_cob_ids() -> None:
    dictionary = Dictionary()
    patch5, forces70 = dictionary.view(5), dictionary.view(70)
    assert patch5 is not None and forces70 is not None
    assert sorted(patch5.pdos) == [0x185, 0x205, 0x285, 0x305, 0x385, 0x405, 0x485]
    assert sorted(forces70.pdos) == [0x1C6, 0x246, 0x2C6, 0x346, 0x3C6, 0x446, 0x4C6, 0x546]
    patch6 = dictionary.view(6)
    assert patch6 is not None and patch6.od is patch5.od  # one parse per EDS
    assert dictionary.view(0) is None and dictionary.view(128) is None


def test_a_force_nodes_taxel_status_reads_as_the_decoders_reason() -> None:
    """0x2004 of a force node is the decoder's reason code, not a patch's pillar bits."""
    from canbus.tools.pdo_dictionary import Dictionary
    from decoder.reasons import Reason

    forces, patch = Dictionary().view(65), Dictionary().view(1)
    assert forces is not None and patch is not None
    assert forces.named(0x2004, 5, float(Reason.EXTRAPOLATED)).text == "S4=EXTRAPOLATED"
    assert forces.named(0x2004, 1, 0.0).text == "S0=ok"
    assert patch.named(0x2004, 1, 1.0).text == "S0=z open"
