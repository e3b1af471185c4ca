"""``--realtime PRIO``: run a command's threads under SCHED_FIFO, like a device driver.

A robot PC runs the planner, cameras and a policy beside the skin host. Under the
default scheduler (CFS) a CPU-bound neighbour gets its fair share while the host's
receive thread waits with frames queued; under SCHED_FIFO the host's threads run as
soon as they are ready and until they block, ahead of every normal process. The host
needs little CPU (docs/host.md, "On a busy computer"), so it cannot starve the rest.

Like ``--cpu``, the policy is set on the calling thread before the command starts any
thread: Linux gives every thread created afterwards its creator's policy and priority.
A process that may not (no ``CAP_SYS_NICE``, no ``LimitRTPRIO`` in its systemd unit, an
``RLIMIT_RTPRIO`` below the priority) runs as before, after one warning line that says so.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from contextlib import contextmanager

from skin.commands.common import argtypes

logger = logging.getLogger(__name__)

MIN_PRIORITY, MAX_PRIORITY = 1, 99
DEFAULT_PRIORITY = 50
"""Below the kernel's threaded interrupt handlers (50 by default, FIFO) would starve a
CAN adapter's interrupts on PREEMPT_RT; 50 shares their level, round-robin by arrival."""


priority = argtypes.count("priority", MIN_PRIORITY, MAX_PRIORITY)
"""An argparse type: a SCHED_FIFO priority 1..99."""


@contextmanager
def realtime(prio: int | None) -> Iterator[bool]:
    """Run the calling thread, and the threads it starts meanwhile, under SCHED_FIFO at
    ``prio`` (None: as it is); yields whether it does. Restored on exit."""
    if prio is None:
        yield False
        return
    setscheduler = getattr(os, "sched_setscheduler", None)
    if setscheduler is None:
        logger.warning("--realtime: this platform has no SCHED_FIFO; running at normal "
                       "priority")
        yield False
        return
    before = (os.sched_getscheduler(0), os.sched_getparam(0))
    try:
        setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
    except PermissionError:
        logger.warning("--realtime %d: not permitted (needs CAP_SYS_NICE, or LimitRTPRIO=%d "
                       "in the systemd unit); running at normal priority", prio, prio)
        yield False
        return
    try:
        yield True
    finally:
        setscheduler(0, *before)
