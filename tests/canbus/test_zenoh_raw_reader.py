"""A reader written from docs/zenoh.md alone, in another process, with raw zenoh and
struct (no canskin import), decodes the same forces as the host's API."""

from __future__ import annotations

import ast
import json
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh (the zenoh extra) is not installed")

from tests.support.rigs.children import run
from tests.support.rigs.zenoh_host import publishing_host

SCRIPT = Path(__file__).resolve().parents[2] / "examples" / "zenoh_raw_reader.py"
COUNT = 40


def test_the_independent_reader_imports_nothing_of_canskin() -> None:
    tree = ast.parse(SCRIPT.read_text())
    imported = {alias.name.split(".")[0] for node in ast.walk(tree)
                if isinstance(node, ast.Import) for alias in node.names}
    imported |= {node.module.split(".")[0] for node in ast.walk(tree)
                 if isinstance(node, ast.ImportFrom) and node.module}
    assert imported == {"json", "struct", "sys", "threading", "zenoh"}


def test_a_reader_from_the_docs_decodes_the_forces_the_api_gives(tmp_path: Path) -> None:
    out = tmp_path / "raw.jsonl"
    with publishing_host((1, 2)) as rig:
        reader = run([sys.executable, str(SCRIPT), rig.endpoint,
                      "canskin/test-host/*/forces/*", str(COUNT), str(out)], timeout=120)
        api = rig.by_cycle()  # the reader had them: the host's callback ran before
    assert reader.returncode == 0, reader.stderr
    records = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(records) == COUNT
    for r in records:
        frame = api[(r["patch"], r["cycle"])]
        assert r["key"] == f"canskin/test-host/default/forces/{r['patch']}"
        assert r["encoding"] == "application/octet-stream;canskin.forces.v1"
        assert (r["host"], r["bus"], r["force_node"], r["sync_counter"]) == \
            ("test-host", "default", frame.force_node, frame.sync_counter)
        assert r["sync_time"] == frame.timestamp
        assert np.array_equal(np.array(r["forces"]), frame.force_N)
        assert r["valid"] == frame.valid.tolist() and r["reasons"] == frame.reason.tolist()
        assert (r["complete"], r["published"]) == (frame.complete, frame.published)
        assert r["sync_time"] <= r["published_time"] <= r["sent_time"]
        assert r["extensions"] == []
    assert any(max(f[2] for f in r["forces"]) > 0.5 for r in records)
