"""The active host's set-up jobs: one at a time per patch, off the bus threads, retried
with back-off while the patch is heard.

A job identifies the node (0x1018), puts it pre-operational, configures it
(:func:`~canbus.master.patch_setup.setup_patch`), checks what it reports (an R0 of 0, NaN
or -1 is a failure with a reason, not a silent stall), builds and warms its decoder and
starts it by NMT. Whatever a job raises is a failure: logged with its reason (a few lines
per patch every 10 s at most), recorded in the patch's state (``health().error``,
``setup_failures``) and retried after :data:`BACKOFF_MIN_S`, doubling to
:data:`BACKOFF_MAX_S`, for as long as the patch is configuring (heard, not lost: a lost
patch is tried again when it returns, a booted one at once). Only a reason that cannot
change until the node boots again ends in ``failed``: it is not a patch (0x1018), or it
refuses the mapping or objects the config asks for (:data:`REFUSALS`), and only once
the same verdict came :data:`PERMANENT_AFTER` times in a row (a garbled reply is not a
verdict). A boot-up starts the set-up over.
"""

# canopen 2.4 ships py.typed but leaves SdoClient and NmtMaster methods unannotated.
# mypy: disable-error-code="no-untyped-call"
from __future__ import annotations

import heapq
import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from types import MappingProxyType

from canopen.sdo.exceptions import SdoAbortedError

from canbus.identity import Identity
from canbus.master.discovery import read_identity
from canbus.master.patch_setup import (
    PatchSetup,
    check_reported,
    setup_patch,
    warn_if_unlike_config,
)
from canbus.master.policy import HostParts
from canbus.master.records import PatchRecord
from canbus.ratelog import RateLimitedLog
from skin.errors import SkinError

logger = logging.getLogger(__name__)

NMT_START, NMT_PRE_OPERATIONAL = 0x01, 0x80
BACKOFF_MIN_S, BACKOFF_MAX_S = 0.1, 1.0
PERMANENT_AFTER = 3
REFUSALS = MappingProxyType({
    0x06010000: "unsupported access to an object",
    0x06010001: "attempt to read a write-only object",
    0x06010002: "attempt to write a read-only object",
    0x06020000: "object does not exist",
    0x06040041: "object cannot be mapped to the PDO",
    0x06040042: "the mapped objects would exceed the PDO length",
    0x06090011: "sub-index does not exist",
    0x06090030: "value range of parameter exceeded",
})
"""SDO abort codes with which a patch refuses what the config asks of it: a conflict
between the config and the device, not a passing fault."""


class SetupRefusedError(SkinError, RuntimeError):
    """The node cannot be set up as configured until it changes (e.g. it is not a patch)."""


def describe_identity(identity: Identity) -> str:
    return (f"vendor 0x{identity.vendor:08X}, product {identity.product}, "
            f"revision 0x{identity.revision:08X}, serial {identity.serial}")


def verdict(err: BaseException) -> tuple[str, bool]:
    """The reason a set-up failed, and whether it is a refusal (permanent once repeated)."""
    if isinstance(err, SetupRefusedError):
        return str(err), True
    if isinstance(err, SdoAbortedError) and err.code in REFUSALS:
        return f"the patch refused: {err} ({REFUSALS[err.code]})", True
    text = str(err) or type(err).__name__
    return (text if isinstance(err, SkinError) else f"{type(err).__name__}: {text}"), False


@dataclass
class _Slot:
    busy: bool = False  # a job is queued or running
    retry_at: float = 0.0  # time.monotonic(): no new attempt before
    refusal: str | None = None  # the last refusal, and how many times in a row
    refusals: int = 0


class SetupJobs:
    """The set-up jobs of the active host (module docstring)."""

    def __init__(self, parts: HostParts) -> None:
        self.parts = parts
        self.paused = False  # while the scan runs: the scan finds and configures the nodes
        self._slots = {n: _Slot() for n in parts.patches}
        self._lock = threading.Lock()
        self._log = RateLimitedLog(logger)
        self._executor = ThreadPoolExecutor(max_workers=max(1, min(8, len(parts.patches))),
                                             thread_name_prefix="patch-setup")
        self._retries = _Retries(self._retry)

    def ensure(self, patch: PatchRecord) -> Future[None] | None:
        """Start a set-up of the patch if its state asks for one and none is running or
        waiting out its back-off; returns the job started (None: none now)."""
        parts = self.parts
        if self.paused or parts.stopping.is_set():
            return None
        incarnation = parts.states.needs_setup(patch.node_id)
        if incarnation is None:
            return None
        with self._lock:
            slot = self._slots[patch.node_id]
            if slot.busy:
                return None  # it ensures again when it ends
            now = time.monotonic()
            if now < slot.retry_at:
                self._retries.at(slot.retry_at, patch.node_id)
                return None
            slot.busy = True
            try:
                return self._executor.submit(self._run, patch, incarnation)
            except RuntimeError:  # shutting down
                slot.busy = False
                return None

    def submit(self, job: Callable[[int], None], node_id: int) -> Future[None] | None:
        """Run another SDO job (identifying an unknown node) on the set-up workers."""
        if self.parts.stopping.is_set():
            return None
        try:
            return self._executor.submit(job, node_id)
        except RuntimeError:  # shutting down
            return None

    def stop(self) -> None:
        """Halt every SDO transfer and job now (the host stops)."""
        self._retries.stop()
        self._executor.shutdown(wait=False, cancel_futures=True)
        for patch in self.parts.patches.values():
            halt = getattr(patch.node.sdo, "halt", None)
            if callable(halt):
                halt()
        self._executor.shutdown(wait=True)
        self._log.flush()

    # -- a job ---------------------------------------------------------------------------

    def _run(self, patch: PatchRecord, incarnation: int) -> None:
        try:
            setup = self._configure(patch)
        except Exception as err:
            self._failed(patch, incarnation, err)
        else:
            self._succeeded(patch, incarnation, setup)
        finally:
            with self._lock:
                self._slots[patch.node_id].busy = False
        self.ensure(patch)  # a boot-up meanwhile: set up the new incarnation; a failure: retry

    def _configure(self, patch: PatchRecord) -> PatchSetup:
        parts = self.parts
        node = patch.node
        identity = read_identity(node.sdo)
        if identity.kind != "patch":
            raise SetupRefusedError(f"node {patch.node_id} is not a patch: "
                                    f"{describe_identity(identity)}")
        node.nmt.send_command(NMT_PRE_OPERATIONAL)
        setup = setup_patch(node, patch.config.mode, heartbeat_ms=parts.config.heartbeat_ms,
                            fd=patch.link.fd)
        check_reported(setup.info, setup.pillars)
        warn_if_unlike_config(patch.config, setup.info)
        parts.decoders.get(patch.config, setup)  # built and warmed here, not in a cycle
        return setup

    def _succeeded(self, patch: PatchRecord, incarnation: int, setup: PatchSetup) -> None:
        parts = self.parts
        if parts.stopping.is_set():
            return
        with self._lock:
            slot = self._slots[patch.node_id]
            slot.retry_at, slot.refusal, slot.refusals = 0.0, None, 0
        # It answered every SDO request: alive, and judged by our period from now on.
        patch.link.monitor.expect(patch.node_id)
        if parts.states.set_up(patch.node_id, incarnation, setup):
            patch.node.nmt.send_command(NMT_START)
            logger.debug("patch %d configured on bus %r (%s%s, %s)", patch.node_id,
                        patch.link.name, setup.mode, ", CAN FD" if patch.link.fd else "",
                        patch.config.decoder)

    def _failed(self, patch: PatchRecord, incarnation: int, err: Exception) -> None:
        parts = self.parts
        if parts.stopping.is_set():
            return
        reason, refusal = verdict(err)
        with self._lock:
            slot = self._slots[patch.node_id]
            slot.refusals = slot.refusals + 1 if refusal and reason == slot.refusal else \
                int(refusal)
            slot.refusal = reason if refusal else None
            permanent = slot.refusals >= PERMANENT_AFTER
        failures = parts.states.setup_failed(patch.node_id, incarnation,
                                             f"set-up failed: {reason}", permanent=permanent)
        if failures is None or permanent:
            return  # void (it booted since), or the state line says it
        backoff = min(BACKOFF_MIN_S * 2 ** (failures - 1), BACKOFF_MAX_S)
        with self._lock:
            slot.retry_at = time.monotonic() + backoff
        self._log.log(logging.WARNING, patch.node_id, "patch %d: set-up failed (%s); "
                      "attempt %d, again in %.1f s while it is heard", patch.node_id, reason,
                      failures, backoff)

    def _retry(self, node_id: int) -> None:
        self.ensure(self.parts.patches[node_id])


class _Retries:
    """Calls ``call(node_id)`` when each retry is due, on one thread of its own."""

    def __init__(self, call: Callable[[int], None]) -> None:
        self._call = call
        self._due: list[tuple[float, int]] = []
        self._wake = threading.Condition()
        self._stopped = False
        self._thread: threading.Thread | None = None

    def at(self, due: float, node_id: int) -> None:
        with self._wake:
            if self._stopped or any(n == node_id for _, n in self._due):
                return
            heapq.heappush(self._due, (due, node_id))
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="setup-retries",
                                                daemon=True)
                self._thread.start()
            self._wake.notify()

    def stop(self) -> None:
        with self._wake:
            self._stopped = True
            self._due.clear()
            self._wake.notify()
        if self._thread is not None:
            self._thread.join()

    def _run(self) -> None:
        while True:
            with self._wake:
                while not self._stopped and (
                        not self._due or self._due[0][0] > time.monotonic()):
                    self._wake.wait(self._due[0][0] - time.monotonic() if self._due else None)
                if self._stopped:
                    return
                _, node_id = heapq.heappop(self._due)
            try:
                self._call(node_id)
            except Exception:
                logger.exception("patch %d: retrying its set-up failed", node_id)
