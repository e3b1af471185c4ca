"""Long-running commands as real processes: SIGTERM and SIGHUP stop them as Ctrl-C does,
with their summary, their --json and exit status 0 (`skin sniff`: test_record_signals.py)."""

from __future__ import annotations

import json
import signal
import sys
from pathlib import Path

import pytest

from tests.support.rigs.children import Child, spawn

FILES = Path(__file__).parents[1] / "files" / "recordings"


def _stop(proc: Child, sig: signal.Signals) -> tuple[str, str]:
    proc.stop(sig)
    return proc.stdout(), proc.stderr()


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_sim_run(tmp_path: Path, sig: signal.Signals) -> None:
    out = tmp_path / "sim.json"
    proc = spawn([sys.executable, "-m", "skin.cli", "sim", "run", "paper", "-i", "virtual",
                  "-c", f"stop-{sig.name}", "--json", str(out)])
    proc.wait_for("Ctrl-C stops", timeout=60)
    stdout, stderr = _stop(proc, sig)
    assert proc.returncode == 0, stderr
    assert stdout.split("Ctrl-C stops\n")[1].startswith("served 0 SYNCs, sent 0 TPDOs in ")
    assert f"INFO skin.commands.common.signals: stopping on {sig.name}" in stderr
    record = json.loads(out.read_text())
    assert record["stopped_by"] == sig.name and record["scene"] == "paper"


def test_replay(tmp_path: Path) -> None:
    out = tmp_path / "replay.json"
    proc = spawn([sys.executable, "-m", "skin.cli", "replay", "-i", "virtual",
                  str(FILES / "good.log"), "--loop", "--json", str(out)])
    proc.wait_for("pass 1: 8 frames", stream="stderr", timeout=60)
    stdout, stderr = _stop(proc, signal.SIGTERM)
    assert proc.returncode == 0, stderr
    record = json.loads(out.read_text())
    assert record["stopped_by"] == "SIGTERM" and record["passes"] >= 1
    assert record["frames_sent"] >= 8
    assert f"sent {record['frames_sent']:,} frames in " in stdout
    assert stdout.rstrip().endswith("original timing); stopped by SIGTERM")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_run(tmp_path: Path, sig: signal.Signals) -> None:
    """`timeout -s TERM 5 skin run CONFIG --json F` writes F: the host stops, its summary."""
    config = tmp_path / "host.toml"
    config.write_text(f'[bus]\ninterface = "virtual"\nchannel = "stop-run-{sig.name}"\n'
                      "[[patches]]\nnode_id = 1\n")
    out = tmp_path / "run.json"
    proc = spawn([sys.executable, "-m", "skin.cli", "run", str(config), "--json", str(out)])
    proc.wait_for("no patch answered", timeout=60)  # past the scan: the host runs
    stdout, stderr = _stop(proc, sig)
    assert proc.returncode == 0, stderr
    assert f"stopped by {sig.name}" in stdout and "(0 complete, " in stdout  # patch absent
    record = json.loads(out.read_text())
    assert record["stopped_by"] == sig.name and record["patches"]["1"]["state"] == "absent"
    # a time says its clock and unit: never heard, so none
    assert record["patches"]["1"]["last_heartbeat_unix_s"] is None
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp file
