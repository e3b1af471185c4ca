"""Child processes that die with whoever started them, and whose output is kept.

Every process a test or a rig starts goes through :func:`spawn` (or :func:`run` for one
that runs to its end); ``tests/test_suite_rules.py`` checks that nothing else calls
``subprocess`` or ``multiprocessing``. A child:

* is the leader of a process group of its own, so :meth:`Child.kill` (and the suite's
  clean-up) ends it with everything it started;
* gets SIGKILL from the kernel when the thread that started it ends, however it ends
  (``PR_SET_PDEATHSIG``): a killed pytest leaves no orphan. So start children from the
  test's own thread, not from a short-lived helper thread;
* has its output read by two threads into memory as it comes (``stdout=path`` writes it to
  a file instead): :meth:`Child.wait_for` waits for a line with a deadline, and the output is
  at hand when a test fails. ``tests/conftest.py`` kills every child a test leaves running,
  fails that test, and adds each child's output to the report of a test that failed
  (pytest-timeout's included).

    child = spawn([sys.executable, "-m", "skin.cli", "sim", "run", "paper"])
    child.wait_for("Ctrl-C stops", timeout=30)
    assert child.stop(signal.SIGTERM) == 0, child.output()
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO

STOP_TIMEOUT_S = 30.0
CHECKOUT = Path(__file__).resolve().parents[3]
_TAIL = 6000  # characters of each stream a report shows
_PR_SET_PDEATHSIG = 1
_libc = ctypes.CDLL(None, use_errno=True)  # resolved here: the forked child only calls it
started: list[Child] = []
"""Every child started since the suite's clean-up last cleared the list (each test's)."""


def _with_checkout(env: Mapping[str, str] | None) -> dict[str, str]:
    """``env`` (or this process's) with the checkout on PYTHONPATH: a child started in any
    folder can run ``python -m tests.support...``, which is not installed."""
    out = dict(os.environ if env is None else env)
    out["PYTHONPATH"] = os.pathsep.join(p for p in (out.get("PYTHONPATH"), str(CHECKOUT)) if p)
    return out


class _Stream:
    """One output stream: kept whole in memory, lines waited for with a deadline."""

    def __init__(self, pipe: IO[str] | None, path: Path | None) -> None:
        self.path = path
        self.lines: list[str] = []
        self.changed = threading.Condition()
        self.closed = pipe is None
        self.reader = None if pipe is None else threading.Thread(
            target=self._read, args=(pipe,), daemon=True, name="child output")
        if self.reader is not None:
            self.reader.start()

    def _read(self, pipe: IO[str]) -> None:
        with pipe:
            for line in pipe:
                with self.changed:
                    self.lines.append(line)
                    self.changed.notify_all()
        with self.changed:
            self.closed = True
            self.changed.notify_all()

    def text(self) -> str:
        if self.path is not None:
            return self.path.read_text(errors="replace") if self.path.exists() else ""
        with self.changed:
            return "".join(self.lines)

    def finish(self, timeout: float) -> None:
        if self.reader is not None:
            self.reader.join(timeout)


class Child:
    """A running process (see the module docstring); ``popen`` is the ``subprocess.Popen``."""

    def __init__(self, args: Sequence[str], *, cwd: Path | str | None,
                 env: Mapping[str, str] | None, stdout: Path | None, stderr: Path | None,
                 stdin: int | None, tracked: bool = True) -> None:
        self.args = [str(a) for a in args]
        files = [None if p is None else p.open("w") for p in (stdout, stderr)]
        parent = os.getpid()
        try:
            self.popen = subprocess.Popen(
                self.args, cwd=cwd, env=_with_checkout(env), text=True,
                errors="replace", stdin=stdin, start_new_session=True,
                stdout=files[0] or subprocess.PIPE,
                stderr=files[1] or (subprocess.STDOUT if files[0] else subprocess.PIPE),
                preexec_fn=lambda: _die_with(parent))
        finally:
            for f in files:
                if f is not None:
                    f.close()
        self._out = _Stream(self.popen.stdout, stdout)
        self._err = _Stream(self.popen.stderr, stderr)
        if tracked:
            started.append(self)

    def __repr__(self) -> str:
        return f"Child({' '.join(self.args)!r}, pid={self.pid}, returncode={self.returncode})"

    @property
    def pid(self) -> int:
        return self.popen.pid

    @property
    def returncode(self) -> int | None:
        return self.popen.poll()

    @property
    def stdin(self) -> IO[str] | None:
        return self.popen.stdin

    def poll(self) -> int | None:
        return self.popen.poll()

    def running(self) -> bool:
        return self.popen.poll() is None

    def stdout(self) -> str:
        """Everything the child wrote to stdout so far."""
        return self._out.text()

    def stderr(self) -> str:
        return self._err.text()

    def output(self) -> str:
        """Its command, status and both streams (their tails), for an assertion message."""
        parts = [f"$ {' '.join(self.args)}  (pid {self.pid}, exit {self.returncode})"]
        for name, text in (("stdout", self.stdout()), ("stderr", self.stderr())):
            if text:
                cut = "...\n" + text[-_TAIL:] if len(text) > _TAIL else text
                parts.append(f"--- {name}:\n{cut.rstrip()}")
        return "\n".join(parts)

    def wait_for(self, text: str, *, timeout: float, stream: str = "stdout") -> str:
        """The first line of ``stream`` holding ``text``, once it came; AssertionError (with
        the output) if the child ends or ``timeout`` s pass first."""
        out = self._out if stream == "stdout" else self._err
        if out.reader is None:
            raise ValueError(f"{stream} goes to {out.path}: wait on the file instead")
        deadline = time.monotonic() + timeout
        with out.changed:
            while True:
                found = next((line for line in out.lines if text in line), None)
                if found is not None:
                    return found
                left = deadline - time.monotonic()
                if out.closed or left <= 0:
                    raise AssertionError(f"no {text!r} on {stream} within {timeout} s "
                                         f"(exit {self.poll()}):\n{self.output()}")
                out.changed.wait(left)

    def send_signal(self, sig: int) -> None:
        if self.popen.poll() is None:
            self.popen.send_signal(sig)

    def wait(self, timeout: float = STOP_TIMEOUT_S) -> int:
        """Its exit status once it ended and its output was read; AssertionError (with the
        output) after ``timeout`` s, the child killed."""
        try:
            code = self.popen.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            raise AssertionError(f"still running after {timeout} s, killed:\n"
                                 f"{self.output()}") from None
        self._out.finish(timeout)
        self._err.finish(timeout)
        return code

    def stop(self, sig: int = signal.SIGINT, timeout: float = STOP_TIMEOUT_S) -> int:
        """Send ``sig`` (Ctrl-C by default) and wait for the end: the exit status."""
        self.send_signal(sig)
        return self.wait(timeout)

    def kill(self) -> None:
        """SIGKILL to its whole process group, then reap it."""
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.popen.pid, signal.SIGKILL)
        self.popen.wait()
        self._out.finish(5.0)
        self._err.finish(5.0)


def _die_with(parent: int) -> None:
    """In the forked child, before exec: SIGKILL when the parent's thread ends."""
    _libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:  # the parent died before the prctl took effect
        os._exit(1)


def spawn(args: Sequence[str], *, cwd: Path | str | None = None,
          env: Mapping[str, str] | None = None, stdout: Path | None = None,
          stderr: Path | None = None, stdin: int | None = None,
          tracked: bool = True) -> Child:
    """Start ``args`` as a :class:`Child`. ``stdout`` / ``stderr``: files to write to (stderr
    joins stdout's file when only ``stdout`` is given); by default both are kept in
    memory. ``stdin``: ``subprocess.PIPE`` to write to :attr:`Child.stdin`.
    ``tracked=False``: not the current test's to reap, for a runner whose work spans a
    module's tests (tests/docblocks.py runs documents side by side); it still dies with
    the thread that started it, and that runner ends it."""
    return Child(args, cwd=cwd, env=env, stdout=stdout, stderr=stderr, stdin=stdin,
                 tracked=tracked)


def run(args: Sequence[str], *, timeout: float, cwd: Path | str | None = None,
        env: Mapping[str, str] | None = None,
        input: str | None = None) -> subprocess.CompletedProcess[str]:
    """``subprocess.run(args, capture_output=True, text=True, timeout=...)`` as a
    :class:`Child`: killed with its group after ``timeout`` s (AssertionError, output shown)."""
    child = spawn(args, cwd=cwd, env=env, stdin=None if input is None else subprocess.PIPE)
    if input is not None:
        assert child.stdin is not None
        with child.stdin:
            child.stdin.write(input)
    code = child.wait(timeout)
    return subprocess.CompletedProcess(child.args, code, child.stdout(), child.stderr())


def reap() -> list[Child]:
    """Kill every child in :data:`started` that still runs; the ones that did."""
    alive = [child for child in started if child.running()]
    for child in alive:
        child.kill()
    return alive
