"""The range a real patch can have, stated once (skin.constants): the EDS's limits are it,
nothing outside it is written to a patch, and a patch that reports a value outside it is
refused by the host's set-up with one reason naming the object, the value and the range."""

from __future__ import annotations

from collections.abc import Iterator

import canopen
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from canbus.device.patch_node import PatchNode
from canbus.master.patch_setup import ReportedValueError, check_reported, setup_patch
from canbus.od import load_od
from canbus.patch_constants import (
    CONSTANT_SCALES,
    CONSTANTS,
    LSB,
    LSB_SCALE,
    NOMINAL,
    R0_SCALE,
    U32_MAX,
    Scaled,
)
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.errors import ConfigError

OBJECTS: list[tuple[int, int, Scaled]] = [
    (LSB, 0, LSB_SCALE), *((NOMINAL, k, R0_SCALE) for k in (1, 4, 27)),
    *((CONSTANTS, k, s) for k, s in enumerate(CONSTANT_SCALES, start=1))]
"""Every scaled object a patch reports (three R0 of the 27)."""


def _where(index: int, subindex: int) -> str:
    return f"0x{index:04X}" if index == LSB else f"0x{index:04X} sub {subindex}"


@pytest.mark.parametrize(("index", "subindex", "scale"), OBJECTS,
                         ids=[_where(i, s) for i, s, _ in OBJECTS])
def test_the_eds_limits_of_each_object_are_the_range_of_a_real_patch(
        index: int, subindex: int, scale: Scaled) -> None:
    for od in (load_od("skin-patch", 1), canopen.import_od("eds/skin-patch.eds", 1)):
        obj = od[index] if index == LSB else od[index][subindex]
        assert (obj.min, obj.max) == scale.count_range
        assert obj.min <= obj.default <= obj.max


def _outside(scale: Scaled) -> st.SearchStrategy[int]:
    low, high = scale.count_range
    return st.one_of(st.integers(0, low - 1), st.integers(high + 1, U32_MAX))


@settings(max_examples=50)
@given(data=st.data())
def test_no_value_outside_the_range_is_written_to_a_patch(data: st.DataObject) -> None:
    _, _, scale = data.draw(st.sampled_from(OBJECTS))
    value = scale.to_si(data.draw(_outside(scale)))
    with pytest.raises(ConfigError, match=f"^{scale.field}: .* is outside "):
        scale.to_count(value)


@settings(max_examples=50)
@given(data=st.data())
def test_sensor_constants_outside_the_range_are_one_line_naming_the_constant(
        data: st.DataObject) -> None:
    scale = data.draw(st.sampled_from([LSB_SCALE, *CONSTANT_SCALES]))
    value = scale.to_si(data.draw(_outside(scale)))
    with pytest.raises(ConfigError, match=f"^{scale.field}: must be in ") as err:
        SensorConstants(**{scale.field: value})
    assert "\n" not in str(err.value)


class Patch:
    """A patch node and the host's canopen view of it, on one virtual channel."""

    def __init__(self, channel: str) -> None:
        self.device = canopen.Network()
        self.device.NOTIFIER_CYCLE = 0.05
        self.device.connect(interface="virtual", channel=channel)
        self.node = PatchNode(1, constants=DEFAULT_CONSTANTS)
        self.node.attach(self.device)
        self.master = canopen.Network()
        self.master.NOTIFIER_CYCLE = 0.05
        self.master.connect(interface="virtual", channel=channel)
        self.remote = self.master.add_node(canopen.RemoteNode(1, load_od("skin-patch", 1)))
        self.remote.sdo.RESPONSE_TIMEOUT = 1.0

    def set_up(self) -> None:
        """The host's set-up of the patch (canbus.master.setup_jobs): read, map, check."""
        setup = setup_patch(self.remote, "xyz", heartbeat_ms=0)
        check_reported(setup.info, setup.pillars)

    def close(self) -> None:
        self.node.detach()
        self.master.disconnect()
        self.device.disconnect()


@pytest.fixture
def patch(request: pytest.FixtureRequest) -> Iterator[Patch]:
    p = Patch(f"patch-constants-{request.node.name}")
    yield p
    p.close()


@settings(max_examples=40, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_a_patch_reporting_any_value_outside_the_range_is_refused_naming_it(
        patch: Patch, data: st.DataObject) -> None:
    index, subindex, scale = data.draw(st.sampled_from(OBJECTS))
    count = data.draw(_outside(scale))
    good = patch.node.store.value(index, subindex)
    patch.node.store.store(index, subindex, count)  # the firmware's own value
    try:
        with pytest.raises(ReportedValueError) as err:
            patch.set_up()
    finally:
        patch.node.store.store(index, subindex, good)
    low, high = scale.count_range
    reason = str(err.value)
    assert reason.startswith(f"patch 1 reports {_where(index, subindex)} (")
    assert f") = {count} {scale.unit}" in reason and f"outside {low}..{high} {scale.unit}" \
        in reason
    assert reason.count(" = ") == 1  # one object named


def test_the_patch_with_every_value_inside_the_range_is_set_up(patch: Patch) -> None:
    patch.set_up()
