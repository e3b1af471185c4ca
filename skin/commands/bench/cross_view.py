"""What ``skin bench cross`` prints of the promise: one table per source of pairs, then the
count of rows that meet each half of it and the ones that do not."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from skin.benchmarks.judge import FACTOR, HOME_SHARE


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def _share(value: float) -> str:
    return f"{100 * value:.1f}%"


def _cells(r: Mapping[str, Any]) -> list[str]:
    met = "yes" if r["home_met"] and r["away_met"] else (
        "no: home" if not r["home_met"] else "no: away")
    return [r["decoder"], _share(r["flagged_home"]), _share(r["flagged_away"]),
            _pct(r["error_home_pct"]), _pct(r["error_away_pct"]), _pct(r["deconv_away_pct"]),
            _pct(r["bar_pct"]), str(r["compared"] if r["compared"] is not None else "-"), met]


COLUMNS = ["decoder", "flagged home", "flagged away", "home %", "away %", "deconv away %",
           "bar %", "compared", "met"]


def _table(title: str, rows: Sequence[Mapping[str, Any]], caption: str) -> None:
    from skin.commands.common.tables import show

    body = [[f"{r['mode']} {r.get('pair') or r['train'] + ' -> ' + r['test']}", *_cells(r)]
            for r in rows]
    show(title, ["pair", *COLUMNS], body, caption=caption, labels=2)


def print_promise(result: Mapping[str, Any]) -> None:
    caption = (f"floored AveRelErr on the taxels not flagged; bar = {FACTOR:g}x max(deconv "
               f"away, own at home); flagged at home <= {100 * HOME_SHARE:.0f} %")
    _table(f"the promise on the shipped scenes ({result['train_samples']} training, "
           f"{result['test_samples']} test samples)", result["promise"], caption)
    pairs = result["pairs"]
    _table("the promise on scene pairs of skin.benchmarks.pairs "
           f"({pairs['train_samples']} training, "
           f"{pairs['test_samples']} test samples"
           + (f", {pairs['random_pairs']} drawn at random" if pairs["random_pairs"] else "")
           + ")", pairs["rows"], caption)
    rows = [*result["promise"], *pairs["rows"]]
    s = result["summary"]
    print(f"flagged at home <= {100 * HOME_SHARE:.0f} %: met in {s['home_met']} of {s['rows']} "
          f"(largest {_share(s['worst_flagged_home'] or 0.0)}); unflagged error <= "
          f"{FACTOR:g}x max(deconv away, own at home): met in {s['away_met']} of {s['rows']}"
          + (f" (worst {s['worst_error_over_bar']:.2f}x the bar)"
             if s["worst_error_over_bar"] is not None else ""))
    for r in rows:
        if not (r["home_met"] and r["away_met"]):
            where = r.get("pair") or f"{r['train']} -> {r['test']}"
            print(f"  not met: {r['decoder']} {r['mode']} {where}: flagged at home "
                  f"{_share(r['flagged_home'])}, unflagged {_pct(r['error_away_pct'])} % "
                  f"against a bar of {_pct(r['bar_pct'])} % on {r['compared']} components")
