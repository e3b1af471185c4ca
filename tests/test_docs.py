"""Every command block and Python example of README.md and docs/*.md runs as written
(``tests/docblocks.py``: how blocks are found, marked and run)."""

from __future__ import annotations

import os
import sys
import tomllib
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import pytest

from tests import docblocks
from tests.docblocks import Block, Folder


def _run_block(block: Block, where: Folder) -> str | None:
    """None if the block ran as written, else what went wrong."""
    if block.lang == "text":
        return None
    if "skip" in block.marker:
        return None if block.marker["skip"].strip() else "skip without a reason"
    if block.lang == "toml":
        return _toml(block, where)
    env = docblocks.bus_env(block, where.env)
    limit = float(block.marker.get("timeout", docblocks.DEFAULT_TIMEOUT_S))
    background = docblocks.Background(block, where.path, env)
    try:
        if block.lang == "python":
            got = docblocks.run([sys.executable, "-"], where.path, env, limit,
                                stdin="\n".join(block.lines) + "\n")
        elif block.lang in docblocks.SHELL:
            got = docblocks.run(["bash", "-c", docblocks.script(block)], where.path, env, limit)
        else:
            return f"a block tagged {block.lang!r}: tag it text (not run), or sh, or python"
    finally:
        problems = background.stop()
    if got.code != 0:  # which lines failed first: later lines' output may bury them
        failed = [line for line in got.stderr.splitlines()
                  if line.startswith(("doc-test:", "skin: error", "Traceback"))]
        return (f"exit {got.code} after {got.seconds:.1f} s\n" + "\n".join(failed) +
                f"\n{got.stdout[-1500:]}\n{got.stderr[-2500:]}")
    missing = [f for f in block.marker.get("makes", "").split() if not (where.path / f).exists()]
    if missing:
        return f"did not make {', '.join(missing)}"
    if block.marker.get("output") == "exact" and _output(block) != got.stdout + got.stderr:
        return f"printed other than it shows:\n{got.stdout}{got.stderr}"
    return "; ".join(problems) or None


def _output(block: Block) -> str:
    return "".join(line + "\n" for line in block.lines if not line.startswith("$ "))


def _toml(block: Block, where: Folder) -> str | None:
    text = "\n".join(block.lines) + "\n"
    try:
        tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        return f"not TOML: {err}"
    if "[scene]" in text:
        from sim import load_scene

        path = where.path / f"block{block.line}.toml"
        path.write_text(text, encoding="utf-8")
        load_scene(str(path))
    return None


Result = tuple[list[str], list[str]]  # (failures, skipped)


def _run_document(document: Path, tmp: Path) -> Result:
    """Every block of one document, in order, in one working folder."""
    where = docblocks.folder(tmp)
    failures, skipped = [], []
    for block in docblocks.blocks(document):
        missing = docblocks.missing_tools(block)
        if missing:
            skipped.append(f"{block.where}: needs {', '.join(missing)}")
            continue
        if docblocks.held_back(block) is not None:  # the document's other blocks still count
            if not block.marker["long"].strip():
                failures.append(f"{block.where}: long without a reason")
            continue
        problem = _run_block(block, where)
        if problem:
            failures.append(f"{block.where} [{block.lang or 'sh'}]: {problem}")
    return failures, skipped


@pytest.fixture(scope="module")
def results(request: pytest.FixtureRequest,
            tmp_path_factory: pytest.TempPathFactory) -> dict[Path, Future[Result]]:
    """The blocks of every document a selected test names (``-k zenoh``: that one alone),
    the documents run at once (most of a block's time is processes starting and commands
    waiting out their --seconds), each on a bus of its own; the ones with the most to run
    start first, so that the last to start is a short one."""
    selected = {item.callspec.params["document"] for item in request.session.items
                if "document" in getattr(getattr(item, "callspec", None), "params", {})}
    jobs = int(os.environ.get("SKIN_DOCS_JOBS", "3"))
    pool = ThreadPoolExecutor(max_workers=jobs, thread_name_prefix="docs")
    futures = {doc: pool.submit(_run_document, doc, tmp_path_factory.mktemp(doc.stem))
               for doc in sorted(selected, key=docblocks.work, reverse=True)}
    pool.shutdown(wait=False)
    return futures


@pytest.mark.parametrize("document", docblocks.documents(),
                         ids=lambda p: p.relative_to(docblocks.ROOT).as_posix())
def test_every_block_runs_as_written(document: Path,
                                     results: dict[Path, Future[Result]]) -> None:
    failures, skipped = results[document].result()
    assert not failures, "\n\n".join(failures)
    if skipped:
        pytest.skip("; ".join(skipped) + " (not on this machine)")


def test_markers_are_read(tmp_path: Path) -> None:
    text = ("intro\n<!-- doc-test: bus=udp_multicast stop=2 with=\"skin sim run idle\" -->\n"
            "```\nskin sniff -i udp_multicast  # exit 0\nskin x &\n```\n\n```text\nout\n```\n")
    path = tmp_path / "probe.md"
    path.write_text(text, encoding="utf-8")
    block, output = docblocks.blocks(path)
    assert block.marker == {"bus": "udp_multicast", "stop": "2", "with": "skin sim run idle"}
    assert (block.line, output.lang, output.marker) == (3, "text", {})
    assert docblocks.commands(block) == [("skin sniff -i udp_multicast  # exit 0", 0),
                                         ("skin x &", 0)]
    assert "timeout -s TERM --preserve-status 2 skin" in docblocks.script(block)


def test_a_background_command_is_waited_for_and_checked(tmp_path: Path) -> None:
    """``cmd &  # why`` runs in the background like ``cmd &``; ``wait`` waits for it and
    fails the block on its exit status."""
    text = ("```\nsleep 0.2; exit 3 &  # in the background, with a comment\n"
            "touch started\nwait\ntest -e started && touch after\n```\n")
    path = tmp_path / "probe.md"
    path.write_text(text, encoding="utf-8")
    block, = docblocks.blocks(path)
    got = docblocks.run(["bash", "-c", docblocks.script(block)], tmp_path, dict(os.environ),
                        30.0)
    assert got.code == 1 and "background command 1" in got.stderr
    assert (tmp_path / "after").exists()
