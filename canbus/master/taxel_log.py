"""Invalid taxels in the published samples, logged as a rate-limited summary per patch.

A taxel a decoder refuses (out of range, extrapolated, a fault) goes to the bus as "no
value"; a host that runs for hours must say so without a line per sample. Every
``interval_s`` a patch with invalid taxels gets one line: how many taxel-samples, by
reason, and which taxels.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable

import numpy as np

from canbus.master.dataplane import ForceFrame
from decoder.reasons import Reason, reason_name

logger = logging.getLogger(__name__)

INTERVAL_S = 10.0


class TaxelLog:
    """Counts invalid taxels per patch and reason; logs a summary at most every interval."""

    def __init__(self, interval_s: float = INTERVAL_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.interval_s = interval_s
        self.clock = clock
        self._counts: dict[int, Counter[int]] = {}
        self._taxels: dict[int, set[int]] = {}
        self._since: dict[int, float] = {}

    def note(self, frame: ForceFrame) -> None:
        """One published sample (a data plane's thread)."""
        if frame.valid.all():
            return
        now = self.clock()
        patch = frame.patch
        counts = self._counts.setdefault(patch, Counter())
        reasons = frame.reason[~frame.valid]
        counts.update(int(r) for r in reasons.tolist())
        self._taxels.setdefault(patch, set()).update(np.flatnonzero(~frame.valid).tolist())
        since = self._since.setdefault(patch, now)
        if now - since >= self.interval_s:
            self._flush(patch, now - since)
            self._since[patch] = now

    def flush(self) -> None:
        """Log what is counted (the host stops)."""
        now = self.clock()
        for patch in list(self._counts):
            self._flush(patch, now - self._since.pop(patch, now))

    def _flush(self, patch: int, seconds: float) -> None:
        counts, taxels = self._counts.pop(patch, Counter()), self._taxels.pop(patch, set())
        if not counts:
            return
        by_reason = ", ".join(f"{reason_name(r)} x{n}" for r, n in counts.most_common())
        level = logging.INFO if set(counts) <= {Reason.MISSING} else logging.WARNING
        logger.log(level, "patch %d: %d invalid taxel-samples in the last %.0f s (%s); "
                   "taxels %s", patch, sum(counts.values()), seconds, by_reason,
                   ", ".join(map(str, sorted(taxels))))
