# canopen 2.4 leaves LssMaster's methods unannotated.
# mypy: disable-error-code="no-untyped-call"
"""Node-IDs by identity (LSS, CiA 305) with canopen's ``LssMaster``: by hand or at start.

* :func:`assign` gives the patch with a serial number a node-ID: switch state selective
  (vendor, product and revision of the shipped patch EDS, and the serial), configure
  node-ID, optionally store configuration, switch state global to waiting. A patch waiting
  for LSS boots at once with its node-ID; a patch that had another node-ID is reset (NMT
  reset communication) so that it takes the new one.
* :func:`assign_at_start` is the host's step before it scans the bus: every patch the
  config names by serial number (``[[patches]] serial``) gets its node-ID; with
  ``lss = "auto"`` every other patch waiting for LSS (found by ``LssMaster.fast_scan``)
  gets the next free node-ID: first the config's patches without a serial that did not
  answer the bus scan, then the lowest node-ID that nothing uses. ``lss_store = true``
  stores each assignment in the patch (it keeps its node-ID across power cycles).
"""

from __future__ import annotations

import logging
import queue
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import canopen
from canopen.lss import CS_IDENTIFY_NON_CONFIGURED_SLAVE as IDENTIFY_NON_CONFIGURED_SLAVE
from canopen.lss import LssError, LssMaster
from canopen.sdo.exceptions import SdoError

from canbus.device.local_device import eds_identity
from canbus.device.nv_store import NvStore
from canbus.identity import Identity
from canbus.master.discovery import scan
from skin.errors import BusError
from skin.inputs import fields
from skin.inputs.fields import UNCONFIGURED

if TYPE_CHECKING:
    from canbus.master.hostconfig import HostConfig
    from canbus.master.records import PatchRecord

logger = logging.getLogger(__name__)

MAX_AUTO = fields.NODE_IDS.stop - 1
RETRIES = 3


@dataclass(frozen=True)
class Assignment:
    """A node-ID given by LSS: to the patch with ``serial``, ``how`` = "serial" or "auto"."""

    serial: int
    node_id: int
    how: str
    stored: bool
    previous: int | None = None  # the node-ID it had (None: it waited for LSS)


def _serial_of(node: canopen.RemoteNode) -> int | None:
    """The serial number (0x1018 sub 4) of a node that answers SDO; None if it does not."""
    try:
        return int.from_bytes(node.sdo.upload(0x1018, 4)[:4], "little")
    except (SdoError, LssError):
        return None


def _any_waiting(lss: LssMaster) -> bool:
    """Whether any patch answers "identify non-configured remote slave" (CiA 305)."""
    while not lss.responses.empty():
        lss.responses.get_nowait()
    lss.send_identify_non_configured_remote_slave()
    try:
        answer = lss.responses.get(timeout=lss.RESPONSE_TIMEOUT)
    except queue.Empty:
        return False
    return bool(answer) and answer[0] == IDENTIFY_NON_CONFIGURED_SLAVE


def force_node_store(state_dir: str, node_id: int) -> NvStore | None:
    """A force node's non-volatile store in the host's ``state_dir`` (None: in memory):
    ``forces-<node-ID as 8 hex digits>.json``, its serial number being its node-ID."""
    if not state_dir:
        return None
    return NvStore.in_dir(state_dir, "forces", Identity(*eds_identity("skin-forces"),
                                                         serial=node_id))


def assign(network: canopen.Network, serial: int, node_id: int, *, store: bool = False,
           revision: int | None = None) -> Assignment:
    """Give the patch with ``serial`` node-ID ``node_id``; BusError when it does not answer
    or refuses (the message says which step)."""
    fields.node_id(node_id, "node_id")
    vendor, product, eds_revision = eds_identity("skin-patch")
    lss = network.lss
    try:
        lss.send_switch_state_global(lss.WAITING_STATE)
        if not lss.send_switch_state_selective(vendor, product, eds_revision
                                               if revision is None else revision, serial):
            raise BusError(f"no patch with serial number 0x{serial:08X} answered LSS")
        previous = lss.inquire_node_id()
        lss.configure_node_id(node_id)
        if store:
            lss.store_configuration()
        lss.send_switch_state_global(lss.WAITING_STATE)
    except LssError as err:
        raise BusError(f"LSS with the patch of serial number 0x{serial:08X}: {err}") from err
    if previous not in (UNCONFIGURED, node_id):
        network.send_message(0x000, bytes([0x82, previous]))  # reset communication
    logger.info("LSS: patch 0x%08X -> node-ID %d%s", serial, node_id,
                " (stored)" if store else "")
    return Assignment(serial, node_id, "serial", store,
                      None if previous == UNCONFIGURED else previous)


def assign_auto(network: canopen.Network, free: Iterable[int], *,
                store: bool = False) -> list[Assignment]:
    """Every patch waiting for LSS, found one by one by ``LssMaster.fast_scan``, gets the
    next of ``free``; stops when none is left waiting (or no node-ID is)."""
    lss = network.lss
    out: list[Assignment] = []
    ids = iter(free)
    misses = 0
    for _ in range(MAX_AUTO + RETRIES):
        found, identity = lss.fast_scan()
        if not found:
            # A scan also fails when one answer came late (a busy patch): go on while a
            # patch still says it waits for LSS.
            misses += 1
            if misses > RETRIES or not _any_waiting(lss):
                break
            continue
        node_id = next(ids, None)
        if node_id is None:
            lss.send_switch_state_global(lss.WAITING_STATE)
            logger.warning("LSS: no free node-ID left for the patch of serial 0x%08X",
                           identity[3])
            break
        try:
            lss.configure_node_id(node_id)
            if store:
                lss.store_configuration()
        except LssError as err:
            raise BusError(f"LSS with the patch of serial number 0x{identity[3]:08X}: "
                           f"{err}") from err
        finally:
            lss.send_switch_state_global(lss.WAITING_STATE)
        logger.info("LSS: patch 0x%08X -> node-ID %d (auto)", identity[3], node_id)
        out.append(Assignment(identity[3], node_id, "auto", store))
    return out


def assign_at_start(config: HostConfig, records: dict[int, PatchRecord]) -> list[Assignment]:
    """The host's LSS step (see the module's docstring), on every bus with patches:
    ``records`` are the host's patches by node-ID."""
    done: list[Assignment] = []
    for link in {id(r.link): r.link for r in records.values()}.values():
        patches = [r.config for r in records.values() if r.link is link]
        named = [p for p in patches if p.serial is not None]
        if not named and config.lss != "auto":
            continue
        present = set(scan(link.network, config.scan_ms / 1000.0))
        for patch in named:
            assert patch.serial is not None
            if patch.node_id in present and \
                    _serial_of(records[patch.node_id].node) == patch.serial:
                continue  # already there with its node-ID (stored): no LSS needed
            try:
                done.append(assign(link.network, patch.serial, patch.node_id,
                                   store=config.lss_store))
            except BusError as err:
                logger.warning("%s", err)
        if config.lss == "auto":
            present = set(scan(link.network, config.scan_ms / 1000.0))
            taken = present | {a.node_id for a in done} | set(config.other_nodes) | \
                {p.force_node for p in config.patches} | \
                {p.node_id for p in config.patches if p.serial is not None}
            unnamed = [p.node_id for p in patches if p.serial is None and
                       p.node_id not in taken]
            spare = [n for n in fields.NODE_IDS if n not in taken and
                     n not in {p.node_id for p in config.patches}]
            done += assign_auto(link.network, [*unnamed, *spare], store=config.lss_store)
    return done
