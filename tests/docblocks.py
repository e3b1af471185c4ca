"""The command blocks and Python examples of the documentation, found and run as written.

Every fenced block of README.md and docs/*.md is one of:

- commands (a block tagged ``sh``, ``bash``, ``console``, or untagged): each line a command
  line, run in order by one bash; a line ending in ``&`` runs in the background and must
  end with status 0 by the block's end; any other must exit 0, or N where the line (or,
  in a transcript, its output) says ``# exit N``. A block whose lines start with ``$ `` is
  a transcript: its ``$`` lines are the commands, the rest their output (compared when
  the block's marker says ``output=exact``);
- Python (``python``): run as a script;
- TOML (``toml``): parsed, and loaded as a scene when it has a ``[scene]`` table;
- output (``text``): shown, not run.

A block may carry a marker, an HTML comment on the line before its fence:
``<!-- doc-test: key=value key="a value" -->``. Keys:

- ``skip="why"``: not run, and the reason is required (SocketCAN is not on every machine);
- ``bus=udp_multicast``: the block's bus, by python-can's own configuration
  (``$CAN_INTERFACE``, ``$CAN_CHANNEL``, ``$CAN_CONFIG``): a multicast group and UDP port of
  its own, so commands as written (``-i udp_multicast``, or no flag at all) meet there;
- ``with="cmd; cmd"``: commands running in the background for the block's length (a
  simulated robot for a live example), stopped by SIGTERM after it; the block starts once
  each has said it is up (``Ctrl-C stops``, as ``skin sim run`` and ``skin run`` print);
- ``stop=S``: a command that runs until it is stopped is stopped after S seconds by
  SIGTERM, as ``timeout`` does (every ``skin`` the block runs);
- ``together=yes``: the lines run at once ("in two terminals");
- ``timeout=S``: the block's time limit (default 120 s);
- ``makes="f g"``: files the block must have made;
- ``tools="tshark ffmpeg"``: programs it needs; without them it is skipped, saying so;
- ``long="why"``: a block that takes minutes whatever its flags (a full benchmark): run
  when ``SKIN_DOCS_LONG=1`` (a nightly run), else skipped, saying so;
- ``output=exact``: a transcript's output is compared with what its commands print.

The blocks of one document run in order in one working folder (with ``examples/`` and an
empty ``docs/``), so a later block may use what an earlier one made.
"""

from __future__ import annotations

import itertools
import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from tests.support.rigs import children

ROOT = Path(__file__).resolve().parents[1]
SHELL = {"", "sh", "bash", "console", "shell"}
MARKER = re.compile(r"<!--\s*doc-test:(.*?)-->", re.S)
EXIT = re.compile(r"#.*\bexit (\d+)\b")
_groups = itertools.count(1)
DEFAULT_TIMEOUT_S = 120.0
READY_S = 60.0  # for a background command to say it runs


@dataclass
class Block:
    """One fenced block: where it is, its language, its lines and its marker's keys."""

    path: Path
    line: int  # the fence's line, 1-based
    lang: str
    lines: list[str]
    marker: dict[str, str] = field(default_factory=dict)

    @property
    def where(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


def documents() -> list[Path]:
    """README.md and every docs/*.md, wherever their text has moved."""
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def blocks(path: Path) -> list[Block]:
    text = path.read_text(encoding="utf-8").splitlines()
    out: list[Block] = []
    k = 0
    while k < len(text):
        fence = text[k]
        if not fence.startswith("```"):
            k += 1
            continue
        ticks = len(fence) - len(fence.lstrip("`"))
        end = next((j for j in range(k + 1, len(text))
                    if text[j].startswith("`" * ticks) and not text[j].strip("`").strip()),
                   None)
        if end is None:
            raise AssertionError(f"{path}:{k + 1}: a fence that is never closed")
        out.append(Block(path, k + 1, fence.strip("`").strip().lower(), text[k + 1:end],
                         _marker(text, k)))
        k = end + 1
    return out


def _marker(text: list[str], fence: int) -> dict[str, str]:
    """The marker comment ending on the line before the fence (it may span lines)."""
    if fence == 0 or not text[fence - 1].rstrip().endswith("-->"):
        return {}
    start = fence - 1
    while start > 0 and "<!--" not in text[start]:
        start -= 1
    found = MARKER.search("\n".join(text[start:fence]))
    if found is None:
        return {}
    pairs = shlex.split(found.group(1))
    marker = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep:
            raise AssertionError(f"doc-test marker: {pair!r} is not key=value")
        marker[key] = value
    return marker


# -- running -----------------------------------------------------------------------------


@dataclass
class Folder:
    """A document's working folder and the bus its blocks get."""

    path: Path
    env: dict[str, str]


def folder(tmp: Path) -> Folder:
    (tmp / "docs").mkdir(exist_ok=True)
    examples = tmp / "examples"
    if not examples.exists():
        examples.symlink_to(ROOT / "examples")
    env = {k: v for k, v in os.environ.items() if not k.startswith("CAN_")}
    env["HOME"] = str(tmp)  # no ~/.canrc of the machine's
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONPATH"] = str(ROOT)
    return Folder(tmp, env)


def bus_env(block: Block, base: dict[str, str]) -> dict[str, str]:
    env = dict(base)
    if block.marker.get("bus") == "udp_multicast":
        n = next(_groups)
        pid = os.getpid()
        env["CAN_INTERFACE"] = "udp_multicast"
        env["CAN_CHANNEL"] = f"239.74.{200 + pid % 50}.{n % 250 + 1}"
        env["CAN_CONFIG"] = json.dumps({"port": 32000 + (pid % 500) * 8 + n % 8})
    return env


def work(document: Path) -> int:
    """How much a document runs, roughly: its commands and Python examples, and what runs
    beside them (a ``with`` background)."""
    total = 0
    for block in blocks(document):
        if "skip" in block.marker or "long" in block.marker:
            continue
        if block.lang in SHELL:
            total += len(commands(block))
        elif block.lang == "python":
            total += 3
        total += 3 * bool(block.marker.get("with"))
    return total


def held_back(block: Block) -> str | None:
    """Why a ``long`` block is not run now (None: run it)."""
    if "long" not in block.marker or os.environ.get("SKIN_DOCS_LONG") == "1":
        return None
    return f"long ({block.marker['long']}): SKIN_DOCS_LONG=1 runs it"


def missing_tools(block: Block) -> list[str]:
    return [t for t in block.marker.get("tools", "").split() if shutil.which(t) is None]


def commands(block: Block) -> list[tuple[str, int]]:
    """(command line, expected exit status) of a command block, continuations joined."""
    transcript = any(line.startswith("$ ") for line in block.lines)
    out: list[tuple[str, int]] = []
    pending = ""
    for line in block.lines:
        if transcript:
            if line.startswith("$ "):
                out.append((line[2:], _status(line)))
            elif out and EXIT.search(line):
                out[-1] = (out[-1][0], _status(line))
            continue
        if not line.strip():
            continue
        pending += line[:-1] + " " if line.endswith("\\") else line
        if not line.endswith("\\"):
            out.append((pending, _status(pending)))
            pending = ""
    return out


def _status(line: str) -> int:
    found = EXIT.search(line)
    return int(found.group(1)) if found else 0


def script(block: Block) -> str:
    """The bash script of a command block: its lines as written, each followed by a check
    of its exit status; background lines waited for at the end."""
    parts = ["set -u", "fails=0"]
    stop = block.marker.get("stop")
    if stop:
        parts.append(f'skin() {{ timeout -s TERM --preserve-status {float(stop):g} '
                     'skin "$@"; }')
    lines = commands(block)
    if block.marker.get("together"):
        for k, (line, _) in enumerate(lines):
            parts.append(f"(\n{line}\n) & pid{k}=$!")  # a line may end in a comment
        for k, (line, want) in enumerate(lines):
            parts.append(_check(f"wait $pid{k}", line, want))
        return "\n".join(parts) + '\nexit "$fails"\n'
    background, waiting = 0, []
    for line, want in lines:
        if _in_background(line):
            parts.append(f"{line}\nbg{background}=$!")  # a line of its own: after a comment
            waiting.append(background)
            background += 1
        elif line.split("#", 1)[0].strip() == "wait":  # every background command: checked
            parts += [_check(f"wait $bg{k}", f"background command {k + 1}", 0) for k in waiting]
            waiting = []
        else:
            parts.append(_check(line, line, want))
    parts += [_check(f"wait $bg{k}", f"background command {k + 1}", 0) for k in waiting]
    return "\n".join(parts) + '\nexit "$fails"\n'


def _in_background(line: str) -> bool:
    """The line ends in ``&``, before any comment (``cmd &  # why``)."""
    try:
        words = shlex.split(line, comments=True)
    except ValueError:
        return line.rstrip().endswith("&")
    return bool(words) and words[-1] == "&"


def _check(run: str, what: str, want: int) -> str:
    quoted = shlex.quote(what)
    return (f"{run}\nst=$?; if [ $st -ne {want} ]; then echo \"doc-test: exit $st, not {want}:"
            f" \"{quoted} >&2; fails=1; fi")


@dataclass
class Outcome:
    code: int
    stdout: str
    stderr: str
    seconds: float


def run(argv: list[str], cwd: Path, env: dict[str, str], timeout_s: float,
        stdin: str | None = None) -> Outcome:
    """Run ``argv`` as a child of its own process group; at the limit, the group is killed."""
    started = time.monotonic()
    child = children.spawn(argv, cwd=cwd, env=env, stdin=subprocess.PIPE, tracked=False)
    assert child.stdin is not None
    with child.stdin:
        child.stdin.write(stdin or "")
    try:
        code = child.wait(timeout_s)
    except AssertionError:  # killed at the limit
        return Outcome(-1, child.stdout(), child.stderr() + f"\ndoc-test: over the "
                       f"{timeout_s:g} s limit", time.monotonic() - started)
    return Outcome(code, child.stdout(), child.stderr(), time.monotonic() - started)


class Background:
    """The marker's ``with`` commands, started before a block and stopped after it. Each
    is a long-running ``skin`` command: the block starts once each said "Ctrl-C stops"
    (its bus open, its nodes or host running)."""

    def __init__(self, block: Block, cwd: Path, env: dict[str, str]) -> None:
        self.commands = [c.strip() for c in block.marker.get("with", "").split(";") if c.strip()]
        self.procs = [children.spawn(["bash", "-c", c], cwd=cwd, env=env, tracked=False)
                      for c in self.commands]
        try:
            for proc in self.procs:
                proc.wait_for("Ctrl-C stops", timeout=READY_S)
        except AssertionError:
            for proc in self.procs:
                proc.kill()
            raise

    def stop(self) -> list[str]:
        """Stop them; what went wrong with any that did not run until stopped."""
        problems = []
        for command, proc in zip(self.commands, self.procs, strict=True):
            early = proc.poll()
            code = proc.stop(signal.SIGTERM, timeout=15) if early is None else proc.wait()
            if early not in (None, 0) or code not in (0, -signal.SIGTERM):
                problems.append(f"{command}: exit {code}: {proc.stderr()[-800:]}")
        return problems
