"""``skin bench cross``: every decoder trained on one scene and tested on the others.

z-only: ``paper``, ``paper-noisy`` and ``indenter`` read through pillar z (their loads are pure
presses, which is what a z-only reading can decode). 3-axis: those three and ``slide`` and
``grasp`` (which shear the taxels, so they are read in 3-axis mode only). Each cell: the share
of taxels the decoder flags EXTRAPOLATED, its floored AveRelErr on the taxels it does not flag,
and the oracle's on the same taxels. Then the promise pair by pair
(:mod:`skin.benchmarks.cross`): on those scenes and on the scene pairs of
:mod:`skin.benchmarks.pairs` (and ``--random N`` drawn ones), the share flagged at home and away
and the unflagged error against 2x the larger of deconv's on the pair and the decoder's own at
home. The run is :func:`skin.benchmarks.runs.run_cross`; this module prints it."""

from __future__ import annotations

from typing import Any


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def print_cross(result: dict[str, Any]) -> None:
    from skin.benchmarks.runs import XYZ_SCENES, Z_SCENES
    from skin.commands.common.tables import show

    oracle = {(o["mode"], o["test"]): o for o in result["oracle"]}
    for mode, scenes in (("z", Z_SCENES), ("xyz", XYZ_SCENES)):
        title = (f"{'z-only' if mode == 'z' else '3-axis'}: floored AveRelErr % on the taxels "
                 "not flagged / the oracle's on the same taxels (share flagged EXTRAPOLATED)")
        caption = (f"{result['train_samples']} training, {result['test_samples']} test "
                   "samples per scene")
        table = [["oracle", "", *[_pct(oracle[mode, t]["ave_rel_err_floored_pct"])
                                  for t in scenes]]]
        rows: dict[tuple[str, str | None], dict[str, str]] = {}
        for c in result["cells"]:
            if c["mode"] != mode:
                continue
            text = (f"{_pct(c['ave_rel_err_floored_pct'])}/"
                    f"{_pct(c['oracle_same_taxels_floored_pct'])} "
                    f"{100 * c['flagged_share']:.0f}%")
            rows.setdefault((c["decoder"], c["train"]), {})[c["test"]] = text
        for (decoder, train), cells in rows.items():
            table.append([decoder, train or "(untrained)", *[cells.get(t, "") for t in scenes]])
        show(title, ["decoder", "trained on", *scenes], table, caption=caption, labels=2)
    bars = result["bars"]
    checked = [b for b in bars["hybrid_vs_deconv"] if b["met"] is not None]
    missed = [b for b in checked if not b["met"]]
    print(f"hybrid <= 1.2x deconv on unseen scenes: met in {len(checked) - len(missed)} of "
          f"{len(checked)} cells")
    for b in missed:
        print(f"  not met: hybrid {b['mode']} {b['train']} -> {b['test']}: "
              f"{_pct(b['hybrid'])} % against {_pct(b['deconv'])} %, ratio {_pct(b['ratio'])}")
    from skin.commands.bench.cross_view import print_promise

    print_promise(result)
