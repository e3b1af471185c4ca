"""Audit a recording of 3-axis patches and their force nodes: is every complete force
sample the decode of one whole patch answer, and is there one sample per SYNC?

The audit reads the recording as an outside client would: the patches' answers are
runs of their 7 TPDOs in COB-ID order (TPDO 1, 5, 2, 6, 3, 7, 4 with the predefined
COB-IDs), decoded here with the analytic decoder; the force samples are read with
canopen's own PDO decoding of ``eds/skin-forces.eds``. Usable as a script::

    python -m tests.support.rigs.answer_audit run.log --patches 1 2
"""

# mypy: disable-error-code="no-untyped-call"
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

import canopen
import numpy as np

from canbus.codes import code_to_resistance
from canbus.master.cobids import predefined_tpdo_cob_ids
from canbus.master.forceframes import forces_to_mN
from canbus.master.hostconfig import FORCE_NODE_OFFSET
from canbus.od import load_od
from canbus.tools.recording import Recording
from decoder.registry import create_decoder
from skin.constants import DEFAULT_CONSTANTS

SYNC = 0x080
COMPLETE = 1 << 15


@dataclass
class PatchAudit:
    node_id: int
    answers: set[tuple[int, ...]] = field(default_factory=set)  # each whole answer, in mN
    samples: int = 0
    complete: int = 0
    mixed: list[int] = field(default_factory=list)  # complete samples matching no answer
    first_sync: int | None = None  # SYNCs counted from the patch's first answer
    split: int = 0  # whole answers with a SYNC between their first and last TPDO
    doubled: int = 0  # SYNC periods holding two whole answers (one of them late)


@dataclass
class Audit:
    syncs: int
    patches: dict[int, PatchAudit]

    def verdict(self) -> dict[str, object]:
        return {"syncs": self.syncs, "patches": {
            str(n): {"answers": len(p.answers), "samples": p.samples, "complete": p.complete,
                     "mixed": len(p.mixed), "split": p.split, "doubled": p.doubled,
                     "syncs_since_first_answer": self.syncs - (p.first_sync or 0)}
            for n, p in self.patches.items()}}


def _answer_mN(payloads: list[bytes]) -> tuple[int, ...]:
    """The forces one whole answer decodes to, in mN as a force node sends them."""
    codes = np.frombuffer(b"".join(payloads), dtype="<u2").reshape(9, 3)
    resistance = code_to_resistance(codes, DEFAULT_CONSTANTS.resistance_lsb_ohm)
    decoded = _DECODER.decode(resistance[None])
    mN, _ = forces_to_mN(decoded.force_N[0], decoded.valid[0])
    return tuple(int(v) for v in mN.reshape(27))


_DECODER = create_decoder("analytic")


def audit(path: str | Path, patches: list[int]) -> Audit:
    tpdo = {n: predefined_tpdo_cob_ids(n) for n in patches}
    order = {n: sorted(ids) for n, ids in tpdo.items()}  # the answer: ascending COB-ID
    runs: dict[int, list[bytes | None]] = {n: [None] * 7 for n in patches}  # by TPDO
    place = {n: 0 for n in patches}
    result = Audit(0, {n: PatchAudit(n) for n in patches})
    force_nodes = {}
    for n in patches:
        node = canopen.RemoteNode(n + FORCE_NODE_OFFSET, load_od("skin-forces",
                                                                 n + FORCE_NODE_OFFSET))
        canopen.Network().add_node(node)
        node.tpdo.read(from_od=True)
        force_nodes[n] = node
    pending: dict[int, dict[int, bytes]] = {n: {} for n in patches}
    split = {n: False for n in patches}  # a SYNC came inside the answer being read
    whole = {n: 0 for n in patches}  # whole answers since the last SYNC
    force_ids = {cob: (n, k) for n in patches
                 for k, cob in enumerate(predefined_tpdo_cob_ids(n + FORCE_NODE_OFFSET))}
    owner = {cob: (n, k) for n, ids in tpdo.items() for k, cob in enumerate(ids)}
    with Recording(path) as recording:
        for msg in recording:
            cob = msg.arbitration_id
            if cob == SYNC:
                result.syncs += 1
                for n in patches:
                    split[n] = split[n] or place[n] > 0
                    result.patches[n].doubled += whole[n] > 1
                    whole[n] = 0
            elif cob in owner:
                n, k = owner[cob]
                if cob == order[n][place[n]]:
                    runs[n][k] = bytes(msg.data)
                    place[n] += 1
                    if place[n] == 7:
                        payloads = [p for p in runs[n] if p is not None]
                        result.patches[n].answers.add(_answer_mN(payloads))
                        result.patches[n].split += split[n]
                        whole[n] += 1
                        if result.patches[n].first_sync is None:
                            result.patches[n].first_sync = result.syncs - 1
                        place[n] = 0
                        split[n] = False
                else:  # a broken answer: start again at its first TPDO
                    place[n] = 1 if cob == order[n][0] else 0
                    split[n] = False
                    if place[n]:
                        runs[n][k] = bytes(msg.data)
            elif cob in force_ids:
                n, k = force_ids[cob]
                pending[n][k] = bytes(msg.data)
                if k == 6:
                    _force_sample(result.patches[n], force_nodes[n], pending[n])
                    pending[n] = {}
    return result


def _force_sample(patch: PatchAudit, node: canopen.RemoteNode, frames: dict[int, bytes]) -> None:
    patch.samples += 1
    if len(frames) != 7:
        return
    values: dict[tuple[int, int], int] = {}
    for k, pdo in enumerate(list(node.tpdo.values())[:7]):  # the forces (TPDO 8: contact)
        pdo.on_message(pdo.cob_id, bytearray(frames[k]), 0.0)
        values.update({(v.index, v.subindex): v.raw for v in pdo})
    forces = tuple(values[(0x2000, s)] for s in range(1, 28))
    complete = bool(values[(0x2005, 0)] & COMPLETE)
    if not complete:
        return
    patch.complete += 1
    if forces not in patch.answers:
        patch.mixed.append(patch.samples)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording")
    parser.add_argument("--patches", type=int, nargs="+", required=True)
    args = parser.parse_args()
    result = audit(args.recording, args.patches)
    print(json.dumps(result.verdict(), indent=2))
    return 1 if any(p.mixed for p in result.patches.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
