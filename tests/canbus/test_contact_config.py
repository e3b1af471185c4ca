"""The host config's contact keys, and what a host does with them on the bus."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canbus.master.contactconfig import patch_contact, take_pitch
from canbus.master.forcenode import ForceNode
from canbus.master.hostconfig import HostConfig, PatchConfig, load_host_config
from skin.constants import SensorConstants
from skin.contact import ContactParams
from skin.errors import ConfigError

PATCH = "[[patches]]\nnode_id = 1\n"


def _load(tmp_path: Path, text: str) -> HostConfig:
    path = tmp_path / "host.toml"
    path.write_text(text, encoding="utf-8")
    return load_host_config(path)


def test_contact_defaults_a_table_and_a_patch_s_own_values(tmp_path: Path) -> None:
    assert _load(tmp_path, PATCH).contact == ContactParams()
    config = _load(tmp_path, "[contact]\nfriction = 0.8\nonset_N = 0.5\n" + PATCH
                   + "orientation_deg = 90\nposition_m = [0.1, 0.2]\n"
                   "contact = { release_N = 0.25 }\n[[patches]]\nnode_id = 2\n")
    assert config.contact == ContactParams(onset_N=0.5, friction=0.8)
    one, two = config.patches
    assert one.contact == ContactParams(onset_N=0.5, release_N=0.25, friction=0.8)
    assert two.contact is None and one.orientation_deg == 90.0
    judge = patch_contact(one, config)
    assert judge is not None and judge.params == one.contact
    assert judge.geometry.position_m == (0.1, 0.2) and judge.geometry.orientation_deg == 90.0
    np.testing.assert_allclose(judge.geometry.place((0.01, 0.0)), (0.1, 0.21), atol=1e-15)
    other = patch_contact(two, config)
    assert other is not None and other.params == config.contact
    take_pitch(judge, SensorConstants(taxel_pitch_m=0.02))  # what the patch reports
    assert judge.geometry.pitch_m == 0.02 and judge.geometry.position_m == (0.1, 0.2)


def test_contact_off(tmp_path: Path) -> None:
    config = _load(tmp_path, "[contact]\nenabled = false\n" + PATCH)
    assert config.contact is None and patch_contact(config.patches[0], config) is None


@pytest.mark.parametrize(("text", "expected"), [
    ("[contact]\nfriction = 0.0\n" + PATCH, "contact.friction: must be > 0"),
    ("[contact]\nfriction = \"high\"\n" + PATCH, "contact.friction: must be a number"),
    ("[contact]\nrelease_N = 0.5\n" + PATCH, "contact.release_N: must be in (0, onset_N"),
    ("[contact]\nenabled = 1\n" + PATCH, "contact.enabled: must be true or false"),
    ("[contact]\nstiction = 1\n" + PATCH, "contact.stiction: unknown key"),
    ("contact = 3\n" + PATCH, "contact: must be a table"),
    (PATCH + "contact = { friction = -1 }\n", "patches[0].contact.friction: must be > 0"),
    (PATCH + "contact = { enabled = false }\n", "patches[0].contact.enabled: unknown key"),
    (PATCH + "contact = { near_slip_margin = 1.0 }\n",
     "patches[0].contact.near_slip_margin: must be in [0, 1)"),
    ("[contact]\nenabled = false\n" + PATCH + "contact = { friction = 0.9 }\n",
     "patches[0].contact: the contact summary is off"),
    (PATCH + "orientation_deg = \"north\"\n", "patches[0].orientation_deg: must be a number"),
    (PATCH + "orientation_deg = inf\n", "patches[0].orientation_deg: must be a finite number"),
])
def test_bad_contact_keys_name_their_field(tmp_path: Path, text: str, expected: str) -> None:
    with pytest.raises(ConfigError) as info:
        _load(tmp_path, text)
    assert f"{info.value.field}: {info.value.problem}".startswith(expected), str(info.value)


def test_the_contact_tpdo_has_a_cob_id_of_its_own_in_the_check(tmp_path: Path) -> None:
    eight = "force_cob_ids = [0x1E0, 0x1E1, 0x1E2, 0x1E3, 0x1E4, 0x1E5, 0x1E6, 0x1E7]\n"
    assert _load(tmp_path, PATCH + eight).patches[0].force_cob_ids == tuple(range(0x1E0, 0x1E8))
    with pytest.raises(ConfigError, match=r"host\.toml: patches\[0\]\.force_cob_ids: lists 9 "
                                          r"values, at most 8 allowed"):
        _load(tmp_path, PATCH + eight.replace("0x1E7]", "0x1E7, 0x1E8]"))
    # TPDO 8 of force node 65 is 0x541 by default: a given TPDO on it clashes, named
    clash = PATCH + "force_cob_ids = [0x541, 0x1E1, 0x1E2, 0x1E3, 0x1E4, 0x1E5, 0x1E6]\n"
    with pytest.raises(ConfigError, match=r"host\.toml: patches\[0\]\.force_cob_ids\[0\]: "
                                          r"0x541 \(patches\[0\]\.force_node TPDO 1\) is also "
                                          r"patches\[0\]\.force_node TPDO 8"):
        _load(tmp_path, clash)


def test_a_force_node_without_a_contact_judge_sends_no_contact_pdo() -> None:
    force = np.zeros((9, 3))
    force[4, 2] = 2.0
    with_judge = ForceNode(65, 1).frames(force, np.ones(9, bool), True)
    without = ForceNode(65, 1, contact=None).frames(force, np.ones(9, bool), True)
    assert [c for c, _ in with_judge] == [c for c, _ in without] + [0x541]
    assert with_judge[:7] == without


def test_the_host_puts_each_patch_s_judge_on_its_force_node() -> None:
    import can

    from canbus.master.host import HostManager

    config = HostConfig(patches=(PatchConfig(1, position_m=(0.0, 0.1), orientation_deg=45.0,
                                             contact=ContactParams(friction=0.9)),
                                 PatchConfig(2)), listen_only=True, scan=False)
    with can.Bus(interface="virtual", channel="contact-config") as bus:
        host = HostManager(bus, config)
        one, two = (host.patches[n].force_node for n in (1, 2))
        assert one.contact is not None and one.contact.params.friction == 0.9
        assert one.contact.geometry.orientation_deg == 45.0
        assert two.contact is not None and two.contact.params == ContactParams()
        assert one.store.value(0x2009, 4) == 900  # friction 0.9 in thousandths
        off = HostManager(bus, HostConfig(patches=(PatchConfig(1),), contact=None,
                                          listen_only=True, scan=False))
        assert off.patches[1].force_node.contact is None


def test_a_batch_places_each_patch_s_cop_by_its_own_placement() -> None:
    from canbus.master.contact import PatchContact, summarize_batch
    from skin.contact import PatchGeometry

    judges = [PatchContact(PatchGeometry(0.015, (0.1, 0.0), 90.0)),
              PatchContact(PatchGeometry(0.02, (0.0, -0.3), -30.0)),
              PatchContact(PatchGeometry(0.015, (0.1, 0.0), 90.0))]
    force = np.zeros((3, 9, 3))
    force[:, 5] = (0.3, 0.0, 2.0)  # taxel 5: one pitch to the right of the centre
    batch = summarize_batch(judges, force, np.ones((3, 9), dtype=bool))
    for i, judge in enumerate(judges):
        row = batch.row(i)
        assert row.cop_m.tolist() == [judge.geometry.pitch_m, 0.0]
        np.testing.assert_allclose(row.cop_placed_m, judge.geometry.place(row.cop_m),
                                   atol=1e-15)
        np.testing.assert_allclose(row.force_placed_N[:2],
                                   judge.geometry.rotation @ row.force_N[:2], atol=1e-15)
    np.testing.assert_allclose(batch.row(0).cop_placed_m, (0.1, 0.015), atol=1e-15)
    assert batch.row(0).onset and batch.row(2).onset  # two patches' first samples


def test_a_patch_queued_twice_in_a_batch_is_judged_in_order() -> None:
    from canbus.master.contact import PatchContact, summarize_batch

    judge = PatchContact()
    force = np.zeros((3, 9, 3))
    force[:2, 4, 2] = 1.0  # pressed, pressed, released: cycles k, k+1, k+2 of one patch
    batch = summarize_batch([judge] * 3, force, np.ones((3, 9), dtype=bool))
    assert batch.onset.tolist() == [True, False, False]
    assert batch.release.tolist() == [False, False, True]
    assert batch.in_contact.tolist() == [True, True, False] and judge.state == 0
