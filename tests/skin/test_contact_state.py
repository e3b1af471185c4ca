"""Contact over time (skin.contact_state): hysteresis, onset and release, slip, unknown."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from skin.contact import ContactParams, summarize
from skin.contact_state import step, track

PARAMS = ContactParams(taxel_contact_N=0.1, onset_N=0.3, release_N=0.2, friction=0.5,
                       near_slip_margin=0.2)


def pressed(fz: list[float], shear: list[float] | None = None,
            valid: list[bool] | None = None):  # type: ignore[no-untyped-def]
    """One patch, the centre taxel pressed with ``fz``, sheared along x."""
    n = len(fz)
    force = np.zeros((n, 9, 3))
    force[:, 4, 2] = fz
    force[:, 4, 0] = shear if shear is not None else 0.0
    ok = np.ones((n, 9), dtype=bool)
    if valid is not None:
        ok[~np.array(valid)] = False
    return summarize(force, ok, params=PARAMS)


def test_contact_has_hysteresis_and_one_onset_and_one_release() -> None:
    fz = [0.0, 0.25, 0.31, 0.25, 0.21, 0.25, 0.19, 0.25, 0.0]
    _, b = track(pressed(fz), PARAMS)
    assert b.in_contact.tolist() == [False, False, True, True, True, True, False, False, False]
    assert np.flatnonzero(b.onset).tolist() == [2]
    assert np.flatnonzero(b.release).tolist() == [6]


def test_a_sample_without_a_valid_taxel_holds_the_state_and_reports_no_event() -> None:
    fz = [1.0, 0.0, 0.0, 1.0, 0.0]
    valid = [True, False, False, True, True]
    state, b = track(pressed(fz, valid=valid), PARAMS)
    assert b.in_contact.tolist() == [True, True, True, True, False]
    assert np.flatnonzero(b.onset).tolist() == [0]
    assert np.flatnonzero(b.release).tolist() == [4]
    assert state == 0


def test_slip_enters_on_the_cone_and_leaves_below_the_near_slip_band() -> None:
    shear = [0.0, 0.3, 0.45, 0.5, 0.42, 0.41, 0.39, 0.5, 0.5]
    fz = [1.0] * 8 + [0.1]  # released at the end: no slip without contact
    _, b = track(pressed(fz, shear), PARAMS)
    assert b.slipping.tolist() == [False, False, False, True, True, True, False, True, False]
    assert np.flatnonzero(b.slip_onset).tolist() == [3, 7]
    assert b.near_slip.tolist() == [False, False, True, True, True, True, False, True, False]


samples = st.integers(1, 40).flatmap(lambda n: st.tuples(
    hnp.arrays(np.float64, (n,), elements=st.floats(0.0, 1.0)),
    hnp.arrays(np.float64, (n,), elements=st.floats(-0.8, 0.8)),
    hnp.arrays(np.bool_, (n,))))


@given(samples)
def test_stepping_a_sample_at_a_time_equals_tracking_the_sequence(
        sample: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    fz, shear, valid = sample
    instant = pressed(fz.tolist(), shear.tolist(), valid.tolist())
    final, tracked = track(instant, PARAMS)
    state = np.zeros(1, dtype=np.uint8)
    for i in range(len(fz)):
        one = pressed([fz[i]], [shear[i]], [bool(valid[i])])
        state, b = step(state, one, onset_N=PARAMS.onset_N, release_N=PARAMS.release_N,
                        friction=PARAMS.friction, near_slip_ratio=PARAMS.near_slip_ratio)
        for name in ("in_contact", "onset", "release", "slipping", "slip_onset", "near_slip"):
            assert getattr(b, name)[0] == getattr(tracked, name)[i], (name, i)
    assert int(state[0]) == final
    assert not (tracked.slipping & ~tracked.in_contact).any()
    assert not (tracked.onset & tracked.release).any()


def test_a_summary_row_gives_plain_values() -> None:
    _, b = track(pressed([0.0, 2.0], [0.0, 1.5]), PARAMS)
    row = b.row(1)
    assert row.in_contact and row.onset and row.slipping and row.slip_onset
    assert row.force_N.tolist() == [1.5, 0.0, 2.0] and row.cop_defined
    d = row.to_dict()
    assert d["taxels_in_contact"] == 1 and d["tangential_ratio"] == 0.75
    assert row.contact_area_m2 == d["contact_area_m2"] == 0.015 ** 2
    assert d["contact_taxels"][4] and d["taxel_slip"][4] and not d["partial"]
    assert "slipping" in repr(row) and "cop=(+0.00, +0.00) mm" in repr(row)
    assert "cop=none" in repr(b.row(0))
