"""Hand-made mutants of the core invariants: the suite must kill every one.

    python -m tests.support.mutants [--list] [--full] [NAME ...]

Each mutant is one edit of the product that breaks a promise a user relies on: answers
never mixed across SYNC cycles, a faulty taxel masked and its neighbours still decoded,
a recording complete on SIGTERM and at most 0.1 s short on kill -9, an OS error as one
line. For each, in a copy of the checkout (the files git tracks): the edit is applied
(its text must be found exactly once), the tests that guard the invariant run (``--full``:
the whole suite), and the mutant is killed when a test fails. The unmutated copy runs
the same tests first: they must pass, or no verdict means anything. Run from a checkout
with the test extra installed; exit status 0 when every mutant was killed.
(docs/testing.md)
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class Mutant:
    name: str
    invariant: str
    path: str
    before: str
    after: str
    tests: tuple[str, ...]


MUTANTS = (
    Mutant("tail-joins-the-next-answer",
           "answers never mixed: a frame out of its answer's order is turned away",
           "canbus/answers.py",
           "        if place != slot.next or slot.ended or slot.done:",
           "        if slot.done:",
           ("tests/canbus/test_dataplane_answers.py",
            "tests/canbus/test_answers_multiprocess.py")),
    Mutant("cycle-closes-when-sync-is-sent",
           "a receive thread behind the bus loses nothing: a cycle closes where the bus "
           "passed the next SYNC",
           "canbus/master/dataplane.py",
           "            if self._cycle is None and not self._passage and not self.sync_echo:",
           "            if True:",
           ("tests/canbus/test_dataplane_answers.py",)),
    Mutant("window-ignored",
           "answers never mixed: a frame stamped after its cycle's window is not its cycle's",
           "canbus/answers.py",
           "            if self._start <= msg.timestamp <= self._end:",
           "            if self._start <= msg.timestamp:",
           ("tests/canbus/test_dataplane_answers.py", "tests/canbus/test_dataplane.py",
            "tests/canbus/test_host.py")),
    Mutant("faulty-taxel-not-masked",
           "a taxel its patch reports faulty (EMCY) is masked, never decoded",
           "canbus/master/publisher.py",
           "        reason[masked] = Reason.FAULTY",
           "        reason[masked & False] = Reason.FAULTY",
           ("tests/canbus/test_host.py", "tests/canbus/test_dataplane.py")),
    Mutant("neighbours-masked-too",
           "a faulty taxel's neighbours still decode",
           "canbus/master/publisher.py",
           "        valid = reason == 0",
           "        valid = (reason == 0) & (reason == 0).all(axis=1, keepdims=True)",
           ("tests/canbus/test_host.py", "tests/canbus/test_dataplane.py")),
    Mutant("open-pillar-decoded",
           "an open pillar (infinite resistance) is masked OPEN, never a force or NaN",
           "decoder/reasons.py",
           "    code[r == np.inf] = Reason.OPEN",
           "    code[r == -1.0] = Reason.OPEN",
           ("tests/decoder/test_contract.py", "tests/decoder/test_analytic.py")),
    Mutant("stop-drops-the-queue",
           "SIGTERM keeps every frame received: a stop writes out what is queued",
           "canbus/tools/recorder.py",
           "        self._finished = True",
           "        self._finished = True\n        self._pending.clear()",
           ("tests/canbus/test_record_stream.py", "tests/canbus/test_record_signals.py")),
    Mutant("flush-every-half-second",
           "kill -9 loses at most the last 0.1 s: a frame is on disk FLUSH_S after it came",
           "canbus/tools/recorder.py",
           "FLUSH_S = 0.1",
           "FLUSH_S = 0.5",
           ("tests/canbus/test_record_stream.py",)),
    Mutant("halted-patch-answers",
           "a patch whose source failed answers no SYNC: never a frozen sample as a live one",
           "canbus/device/patch_server.py",
           "        if failed is not None:\n            self._fail(failed)\n"
           "        if self.failure is not None:\n            return\n",
           "        if failed is not None:\n            self._fail(failed)\n",
           ("tests/canbus/test_patch_server.py",)),
    Mutant("os-error-as-a-traceback",
           "an OS error ends a command in one line on stderr",
           "skin/cli.py",
           "    except (SkinError, OSError) as err:",
           "    except SkinError as err:",
           ("tests/skin/test_os_errors.py",)),
    Mutant("cross-patch-press-split",
           "a press across the border of two patches of one link is one contact",
           "skin/placement.py",
           "ADJOIN_PITCHES = 1.5\n",
           "ADJOIN_PITCHES = 0.5\n",
           ("tests/skin/test_placement.py",)),
    Mutant("link-pose-ignored",
           "a contact on a link is in the link's frame: the patch's pose moves it",
           "skin/placement.py",
           "        rot, t = self.pose.matrix, self.pose.vector\n",
           "        rot, t = np.eye(3), np.zeros(3)\n",
           ("tests/skin/test_placement.py",)),
)


def tracked_copy(into: Path) -> Path:
    """The files git tracks, copied under ``into`` (the checkout's working tree)."""
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True,
                            check=True).stdout.decode().split("\0")
    tree = into / "tree"
    for name in filter(None, listed):
        source, target = ROOT / name, tree / name
        if source.is_file():
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target)
    return tree


def pytest_in(tree: Path, tests: list[str], *, stop_first: bool) -> tuple[int, str]:
    """pytest on ``tests`` in ``tree`` (its modules first on every process's path): the
    exit status and the line naming the first failure (or the last line)."""
    env = {**os.environ, "PYTHONPATH": str(tree), "CANSKIN_HYPOTHESIS_PROFILE": "ci"}
    argv = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rf",
            *(["-x"] if stop_first else []), *tests]
    done = subprocess.run(argv, cwd=tree, env=env, capture_output=True, text=True,
                          timeout=3600)
    lines = done.stdout.splitlines()
    failed = next((line for line in lines if line.startswith(("FAILED tests", "ERROR tests"))),
                  None)
    code = done.returncode
    if code == 2 and failed is not None:  # xdist ends a -x run as "Interrupted" (2)
        code = 1
    return code, failed or (lines[-1] if lines else done.stderr.strip()[-300:])


def apply(tree: Path, mutant: Mutant) -> str:
    """Apply the mutant's edit; the original text of its file."""
    path = tree / mutant.path
    text = path.read_text(encoding="utf-8")
    count = text.count(mutant.before)
    if count != 1:
        raise SystemExit(f"{mutant.name}: {mutant.path} holds its text {count} times, not once")
    path.write_text(text.replace(mutant.before, mutant.after), encoding="utf-8")
    return text


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", metavar="NAME", help="mutants to run (default all)")
    parser.add_argument("--list", action="store_true", help="list the mutants and stop")
    parser.add_argument("--full", action="store_true",
                        help="run the whole suite against each mutant, not its guard tests")
    args = parser.parse_args()
    unknown = set(args.names) - {m.name for m in MUTANTS}
    if unknown:
        parser.error(f"no mutant {sorted(unknown)}; --list names them")
    chosen = [m for m in MUTANTS if not args.names or m.name in args.names]
    if args.list:
        for m in chosen:
            print(f"{m.name:28} {m.path:28} {m.invariant}")
        return 0
    with tempfile.TemporaryDirectory(prefix="canskin-mutants-") as tmp:
        tree = tracked_copy(Path(tmp))
        guards = ["tests"] if args.full else sorted({t for m in chosen for t in m.tests})
        started = time.monotonic()
        code, last = pytest_in(tree, guards, stop_first=False)
        print(f"unmutated: {' '.join(guards)}: exit {code} in "
              f"{time.monotonic() - started:.0f} s ({last})", flush=True)
        if code != 0:
            print("the unmutated tree must pass its guard tests first", file=sys.stderr)
            return 2
        survived = 0
        for mutant in chosen:
            original = apply(tree, mutant)
            started = time.monotonic()
            try:
                code, last = pytest_in(tree, ["tests"] if args.full else list(mutant.tests),
                                       stop_first=True)
            finally:
                (tree / mutant.path).write_text(original, encoding="utf-8")
            verdict = "killed" if code == 1 else ("SURVIVED" if code == 0 else f"exit {code}")
            survived += verdict != "killed"
            print(f"{mutant.name:28} {verdict:9} {time.monotonic() - started:5.0f} s  "
                  f"{mutant.invariant}\n{'':28} {last}", flush=True)
        print(f"{len(chosen) - survived} of {len(chosen)} mutants killed")
        return 0 if survived == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
