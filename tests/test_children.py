"""The suite's clean-up, checked on a pytest of its own: a hung test fails at its timeout
with its child's output shown and the child killed; a test that leaves a child running
fails; and a pytest killed outright (kill -9) leaves no child behind (PR_SET_PDEATHSIG)."""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

from tests.support.rigs.children import spawn
from tests.support.rigs.waiting import wait_until

ROOT = Path(__file__).resolve().parents[1]
INNER = '''
import sys
from pathlib import Path

from tests.support.rigs.children import spawn
from tests.support.rigs.waiting import wait_until

CHILD = [sys.executable, "-c",
         "import time; print('the child is up', flush=True); time.sleep(600)"]


def _started(name):
    child = spawn(CHILD)
    child.wait_for("the child is up", timeout=60)
    Path(name).write_text(str(child.pid))
    return child


def test_hangs():
    _started("hangs.pid")
    wait_until(lambda: False, what="nothing", timeout=600)


def test_leaves_its_child():
    _started("leaves.pid")
'''


def _alive(pid: int) -> bool:
    """The process runs (a zombie, killed but not yet reaped, counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state != "Z"


def _inner_pytest(folder: Path, *args: str) -> list[str]:
    (folder / "test_inner.py").write_text(INNER)
    return [sys.executable, "-m", "pytest", "-p", "tests.conftest", "-p", "no:cacheprovider",
            "-q", "--rootdir", str(folder), *args, str(folder / "test_inner.py")]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT)}


def test_a_hung_test_fails_at_its_timeout_showing_its_child_and_killing_it(
        tmp_path: Path) -> None:
    inner = spawn(_inner_pytest(tmp_path, "--timeout", "5"), cwd=tmp_path, env=_env())
    assert inner.wait(timeout=120) == 1, inner.output()
    out = inner.stdout()
    assert "Timeout" in out and "the child is up" in out and "child pid" in out, out
    assert "test left child processes running" in out  # the other test
    assert "2 failed" in out or ("1 failed" in out and "1 error" in out), out
    for name in ("hangs.pid", "leaves.pid"):
        assert not _alive(int((tmp_path / name).read_text())), name


def test_a_pytest_killed_outright_leaves_no_child(tmp_path: Path) -> None:
    inner = spawn(_inner_pytest(tmp_path, "-k", "hangs"), cwd=tmp_path, env=_env())
    wait_until(lambda: (tmp_path / "hangs.pid").exists(), what="the inner test's child")
    child = int((tmp_path / "hangs.pid").read_text())
    assert _alive(child)
    inner.send_signal(signal.SIGKILL)  # no finally, no fixture teardown, no atexit
    assert inner.wait() == -signal.SIGKILL
    wait_until(lambda: not _alive(child), what=f"the orphan {child} gone")
