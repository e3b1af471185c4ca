"""A patch's raw sample: the resistances of one answer as the patch sent them, before the
host scales or decodes them.

The publisher hands every published batch's raw samples to its raw subscribers
(:meth:`canbus.master.publisher.Publisher.subscribe_raw`,
``HostManager.on_raw_samples``): one :class:`RawSample` per patch per SYNC cycle, complete
or not, whatever its decoder makes of it. What a sample says of each taxel is the data
plane's: a taxel whose PDO did not arrive (or was not trusted) is ``MISSING``, one its patch
reported faulty by EMCY is ``FAULTY``; what a reading says of itself (the reserved codes:
open, saturated, short) is in its value, for :func:`decoder.reasons.classify_resistance`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canbus.master.channel import SampleJob
from decoder.reasons import Reason


@dataclass(frozen=True)
class RawSample:
    """One patch's resistances for one SYNC cycle, as its PDOs carried them."""

    patch: int  # patch node-ID
    cycle: int  # host's SYNC cycle number (1, 2, ...), as in its ForceFrame
    sync_counter: int  # the SYNC counter byte sent (0 without a counter)
    timestamp: float  # when the host sent (or saw) that SYNC
    complete: bool  # every TPDO of one answer of the patch arrived, in order, in the window
    resistance_ohm: NDArray[np.float64]
    """(9, P) ohms, the code times the patch's LSB (0x2001), before the host's scale: +inf
    for the open and saturated codes, 0 for short; NaN where the taxel's PDO is missing."""
    reason: NDArray[np.uint8]
    """(9,) ``Reason.MISSING`` (its PDO absent or not trusted), ``Reason.FAULTY`` (masked
    after its patch's EMCY), else ``Reason.OK``."""

    @property
    def valid(self) -> NDArray[np.bool_]:
        """(9,) the taxels the data plane has a reading of."""
        ok: NDArray[np.bool_] = self.reason == Reason.OK
        return ok


RawSubscriber = Callable[[list[RawSample]], None]
"""Called with each published batch's raw samples, in the order they were published."""


def raw_samples(jobs: Sequence[SampleJob], raw: Mapping[int, NDArray[np.float64]],
                missing: NDArray[np.bool_], masked: NDArray[np.bool_]) -> list[RawSample]:
    """The raw samples of ``jobs``: ``raw[i]`` job i's ``(9, P)`` ohms as unpacked (not
    changed), ``missing`` and ``masked`` ``(n, 9)`` its taxels not received and masked."""
    reason = np.where(masked, np.uint8(Reason.FAULTY),
                      np.where(missing, np.uint8(Reason.MISSING), np.uint8(Reason.OK)))
    out = []
    for i, job in enumerate(jobs):
        resistance = raw[i].copy()
        resistance[missing[i]] = np.nan
        cycle, counter, timestamp = job.cycle
        out.append(RawSample(job.slot.channel.node_id, cycle, counter, timestamp,
                             job.complete, resistance, reason[i]))
    return out
