"""Who sent a PDO: no force value is ever shown under a node that did not send it.

Random host configs (patches in z and xyz, force nodes at their own node-IDs and at COB-IDs
of their own, often other nodes' default COB-IDs, as ``examples/host.toml`` does, another
node with PDOs of its own), their buses written frame by frame with the truth of every
frame (``tests.canbus.skin_traffic``), recorded from a random frame on, read by the
sniffer's line printer and by the force reader, with the config and without it.
"""

from __future__ import annotations

import io
from dataclasses import replace

import can
import canopen
import numpy as np
import pytest
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

from canbus.master.cobids import predefined_tpdo_cob_ids, restricted
from canbus.master.hostconfig import HostConfig, PatchConfig, load_host_config
from canbus.tools.attribution import Attribution, KnownNode, cob_ranges
from canbus.tools.forcereader import ForceNodeSpec, ForceReader, ForceSample
from canbus.tools.pdo_dictionary import Dictionary
from canbus.tools.services import Route, Service, ServiceDecoder
from canbus.tools.sniffer import FrameFilter, Sniffer
from skin.commands.common.known_nodes import known_nodes
from skin.commands.sniff.view import LinePrinter, ViewStats
from skin.errors import ConfigError
from tests.canbus.skin_traffic import Traffic, traffic
from tests.support.rigs.waiting import wait_until

CYCLES = 20
EXAMPLE = load_host_config("examples/host.toml")


def _free_pdo_ids() -> list[int]:
    return [c for c in range(0x181, 0x580) if not restricted(c)]


@st.composite
def configs(draw: st.DrawFn) -> HostConfig:
    count = draw(st.integers(1, 3))
    nodes = draw(st.lists(st.integers(1, 12), min_size=count, max_size=count, unique=True))
    force_nodes = draw(st.lists(st.integers(65, 127), min_size=count, max_size=count,
                                unique=True))
    # custom COB-IDs: often the default TPDOs of nodes that are not on the bus, as
    # examples/host.toml's force node 100 takes those of nodes 96..102
    ghost = draw(st.integers(13, 120))
    borrowed = [predefined_tpdo_cob_ids(ghost + k)[0] for k in range(7) if ghost + k <= 127]
    pool = st.sampled_from(borrowed) | st.sampled_from(_free_pdo_ids())
    patches = []
    for node, force in zip(nodes, force_nodes, strict=True):
        cob_ids = None
        if draw(st.booleans()):
            cob_ids = tuple(draw(st.lists(pool, min_size=7, max_size=7, unique=True)))
        patches.append(PatchConfig(node, mode=draw(st.sampled_from(["z", "xyz"])),
                                   force_node=force if draw(st.booleans()) else 0,
                                   force_cob_ids=cob_ids))
    other = draw(st.lists(st.integers(20, 40), max_size=1))
    config = HostConfig(patches=tuple(patches), force_heartbeat_ms=100,
                        other_nodes=tuple(other))
    try:
        return config.check()  # what the host refuses is no bus
    except ConfigError:
        assume(False)
        raise


def _aliased(config: HostConfig) -> bool:
    """Some remapped node's whole default set of TPDOs carried by other nodes' frames: what
    no listener can tell from the node itself (canbus.tools.attribution's docstring)."""
    sent = {c for p in config.patches for c in p.force_cob_ids or ()}
    return any(p.force_cob_ids is not None and
               set(predefined_tpdo_cob_ids(p.force_node)) <= sent for p in config.patches)


def _truth_decoder(config: HostConfig) -> ServiceDecoder:
    return ServiceDecoder(attribution=Attribution(Dictionary(), known_nodes(config)))


def _lines(decoder: ServiceDecoder, bus: Traffic) -> list[tuple[Route, str]]:
    """Each frame's route and the line `skin sniff --view lines` prints for it."""
    routes: list[Route] = []
    sniffer = Sniffer(decoder, on_frame=lambda msg, where, decoded: routes.append(where))
    printer = LinePrinter(decoder, FrameFilter(), io.StringIO(), ViewStats())
    out = []
    for msg in bus.messages:
        sniffer.on_message_received(msg)
        (line,) = printer.format([(msg, routes[-1], None)])
        out.append((routes[-1], line))
    return out


def _check_lines(config: HostConfig, bus: Traffic, told: bool,
                 truth: list[tuple[Route, str]] | None = None) -> list[tuple[Route, str]]:
    """What the line printer shows, told the config or not, against the truth (the lines
    of a printer told the config: every frame under its sender)."""
    truth = truth or _lines(_truth_decoder(config), bus)
    shown = truth if told else _lines(ServiceDecoder(), bus)
    for (where, line), (true_where, true_line), sent, msg in zip(shown, truth, bus.senders,
                                                                 bus.messages, strict=True):
        if sent is None:
            continue
        assert (true_where.node, true_where.label) == (sent.node, f"TPDO{sent.number}"), \
            f"the truth itself: {msg}"
        if where.node is None:  # named unattributed (or by its COB-ID), its bytes only
            assert where.label in ("unattributed", f"0x{msg.arbitration_id:03X}") and not told
            # the label's column is padded: compare the words, not the spaces between them
            assert line.split()[-len(msg.data) - 1:] == [where.label, *msg.data.hex(" ")
                                                           .split()], line
        else:  # shown under a node: the node that sent it, decoded as the sender's mapping,
            # or as bytes where the mapping seen does not fit the frame
            assert (where.node, where.label) == (sent.node, f"TPDO{sent.number}"), line
            assert line == true_line or line.rstrip().endswith(
                f"{msg.data.hex(' ')} (length {len(msg.data)}, mapping needs 8)"), line
    return truth


def _check_samples(config: HostConfig, bus: Traffic, told: bool) -> list[ForceSample]:
    specs = [ForceNodeSpec(p.force_node, p.node_id, p.force_cob_ids, known=True)
             for p in config.patches] if told else None
    reader = ForceReader(specs)
    got: list[ForceSample] = []
    reader.on_sample(got.append)
    reader.feed(bus.messages)
    reader.process(now=bus.messages[-1].timestamp + 1.0)
    published = {(p.force_node, p.timestamp): p for p in bus.published}
    for sample in got:
        if not sample.valid.any():
            continue  # nothing shown
        truth = published.get((sample.force_node, sample.timestamp))
        assert truth is not None, f"force node {sample.force_node} sent no such sample"
        shown = sample.valid
        assert not (shown & ~truth.valid).any()
        np.testing.assert_array_equal(sample.force_N[shown],
                                      (truth.mN.reshape(9, 3) / 1000.0)[shown])
        if told:
            assert sample.patch == truth.patch
    return got


PADDED = HostConfig(patches=(PatchConfig(1, mode="z", force_node=65, force_cob_ids=(
    0x190, 0x191, 0x192, 0x193, 0x194, 0x195, 0x200)),), force_heartbeat_ms=100).check()
"""Force node 65's TPDO 7 at 0x200: without the config its label, the COB-ID, is shorter
than the label column, which is padded."""


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(config=configs(), seed=st.integers(0, 2**16), start=st.integers(0, 400),
       boot=st.booleans(), sdo=st.booleans())
@example(config=PADDED, seed=0, start=0, boot=True, sdo=False)
def test_no_force_value_is_shown_under_a_node_that_did_not_send_it(
        config: HostConfig, seed: int, start: int, boot: bool, sdo: bool) -> None:
    assume(not _aliased(config))
    whole = traffic(config, cycles=CYCLES, seed=seed, boot=boot, sdo=sdo)
    bus = whole.since(min(start, len(whole.messages) - 1))
    truth = _check_lines(config, bus, told=True)  # told the config: every frame its sender's
    _check_lines(config, bus, told=False, truth=truth)
    for told in (False, True):
        _check_samples(config, bus, told)


def test_with_the_config_every_published_sample_is_read() -> None:
    config = replace(EXAMPLE, force_heartbeat_ms=100)
    bus = traffic(config, cycles=CYCLES, seed=3)
    got = _check_samples(config, bus, told=True)
    assert len(got) == len(bus.published) == 3 * CYCLES


def test_the_example_config_without_the_config() -> None:
    """examples/host.toml: force node 100 on 0x1E0..0x1E6, the default TPDO 1 of nodes
    96..102 (and node 100's own default TPDO 1, 0x1E4, carries its TPDO 5)."""
    config = replace(EXAMPLE, force_heartbeat_ms=100)
    bus = traffic(config, cycles=CYCLES, seed=4)
    shown = _lines(ServiceDecoder(), bus)
    custom = set(config.patch(3).force_cob_ids or ())
    on_custom = [where for (where, _), msg in zip(shown, bus.messages, strict=True)
                 if msg.arbitration_id in custom]
    assert on_custom and all(w.node is None and w.label == "unattributed" for w in on_custom)
    got = _check_samples(config, bus, told=False)
    assert {s.force_node for s in got} == {65, 66}  # and nothing from 96..102, nor 100
    # the heartbeat of 65 and 66 came before their first samples: every one is read
    assert len(got) == 2 * CYCLES


def test_a_remap_seen_by_sdo_names_the_node_without_a_config() -> None:
    """A master that writes force node 100's COB-IDs by SDO (as `skin run` does not, but
    another master may): the sniffer and the reader follow it."""
    config = replace(EXAMPLE, force_heartbeat_ms=100)
    bus = traffic(config, cycles=CYCLES, seed=5)
    cob_ids = config.patch(3).force_cob_ids or ()
    writes = Traffic()
    t = bus.messages[0].timestamp - 0.01
    for n, cob in enumerate(cob_ids):
        t = writes.add(t, 0x600 + 100, bytes([0x23, n, 0x18, 1]) + cob.to_bytes(4, "little"))
        t = writes.add(t, 0x580 + 100, bytes([0x60, n, 0x18, 1, 0, 0, 0, 0]))
    both = Traffic(writes.messages + bus.messages, writes.senders + bus.senders,
                   bus.published)
    lines = _lines(ServiceDecoder(), both)
    labels = {(where.node, where.label) for (where, _), msg in zip(lines, both.messages,
                                                                    strict=True)
              if msg.arbitration_id in cob_ids}
    assert labels == {(100, f"TPDO{n}") for n in range(1, 8)}
    got = _check_samples(config, both, told=False)
    assert sum(s.force_node == 100 for s in got) == CYCLES


def test_a_node_alive_without_its_defaults_is_named() -> None:
    """Force node 100 runs (heartbeat) while none of its default COB-IDs carries a frame:
    it was remapped where this bus did not show it; `silent_nodes` says so."""
    config = replace(EXAMPLE, force_heartbeat_ms=100)
    decoder = ServiceDecoder()
    sniffer = Sniffer(decoder)
    for msg in traffic(config, cycles=CYCLES, seed=6).messages:
        sniffer.on_message_received(msg)
    assert 100 in decoder.attribution.silent_nodes()
    assert not {65, 66, 1, 3} & set(decoder.attribution.silent_nodes())


def test_a_boot_up_forgets_what_sdo_said() -> None:
    dictionary = Dictionary()
    attribution = Attribution(dictionary)
    dictionary.observe(70, 0x1800, 1, (0x1E0).to_bytes(4, "little"))
    attribution.heartbeat(70, 5, 1.0)
    assert attribution.owner(0x1E0) is not None and attribution.owner(0x1E0).source == "sdo"
    attribution.heartbeat(70, 0, 2.0)  # it reset: its parameters are its stored ones again
    assert attribution.owner(0x1E0) is None


def test_two_claims_at_one_level_name_nobody() -> None:
    attribution = Attribution(Dictionary(), [KnownNode(65, "skin-forces", cob_ids=(0x1E0,)),
                                             KnownNode(66, "skin-forces", cob_ids=(0x1E0,))])
    assert attribution.owner(0x1E0) is None
    assert attribution.owner(0x2C1) is not None  # 65's TPDO 2, claimed once


@pytest.mark.parametrize(("cobs", "text"), [([0x1E0, 0x1E1, 0x1E2, 0x2A1], "0x1E0-0x1E2, 0x2A1"),
                                             ([0x181], "0x181")])
def test_cob_ranges(cobs: list[int], text: str) -> None:
    assert cob_ranges(cobs) == text


def test_a_frame_route_is_pdo_with_no_node_when_unattributed() -> None:
    decoder = ServiceDecoder()
    where = decoder.route(can.Message(arbitration_id=0x1E0, data=bytes(8),
                                      is_extended_id=False))
    assert where == Route(Service.PDO, None, "unattributed")


def test_asked_by_sdo_a_force_node_names_its_own_pdos() -> None:
    """`--ask-by-sdo`: force node 100 on 0x1E0..0x1E6 (set as the host sets it, without
    SDO on the bus) answers the asker's SDO reads; its PDOs are then its own."""
    from canbus.master.forcenode import ForceNode
    from canbus.tools.pdo_query import PdoAsker

    channel = "asker"
    device = canopen.Network()
    device.NOTIFIER_CYCLE = 0.05
    device.connect(interface="virtual", channel=channel)
    node = ForceNode(100, 3, heartbeat_ms=50)
    for n, cob in enumerate(range(0x1E0, 0x1E7)):
        node.store.set_data(0x1800 + n, 1, (cob | 0x8000_0000).to_bytes(4, "little"))
        node.store.set_data(0x1800 + n, 1, cob.to_bytes(4, "little"))
    node.attach(device)
    decoder = ServiceDecoder()
    sniffer = Sniffer(decoder)
    try:
        with can.Bus(interface="virtual", channel=channel) as bus:
            asker = PdoAsker(bus, decoder.attribution, timeout_s=1.0)
            notifier = can.Notifier(bus, [sniffer, asker.listener], timeout=0.05)
            try:
                wait_until(lambda: 100 in decoder.attribution.alive,
                           what="a heartbeat of node 100")
                assert decoder.attribution.owner(0x1E0) is None  # not known yet
                assert asker.due() == [100]
                assert asker.ask(100) == "answered"
                wait_until(lambda: decoder.attribution.owner(0x1E6) is not None,
                           what="the answers followed")
            finally:
                notifier.stop()
    finally:
        device.disconnect()
    owners = {cob: decoder.attribution.owner(cob) for cob in range(0x1E0, 0x1E7)}
    assert {(o.node, o.number, o.source) for o in owners.values() if o} == \
        {(100, n, "sdo") for n in range(1, 8)}
    assert asker.due() == []  # asked once (until it boots again)
