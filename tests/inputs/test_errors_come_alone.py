"""A command that fails says one thing, the error: a warning it had for the user before it
found the error (a bus inside this process, a load over the target) is not printed before
it. And a warning about a choice the user made on the command line is not given at all."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests.inputs.hostile import refused, run

READ_ONLY = "/sys/out.json"
"""A folder that exists and takes no new file, even for root."""


def _unavailable_cpu() -> str:
    return str(max(os.sched_getaffinity(0)) + 1)


@pytest.fixture
def virtual_host(tmp_path: Path) -> Path:
    """A host config whose [bus] is the virtual bus: skin run warns that it reaches only
    this process."""
    config = tmp_path / "host.toml"
    config.write_text('[bus]\ninterface = "virtual"\nchannel = "alone"\n\n'
                      "[[patches]]\nnode_id = 1\n")
    return config


COMMANDS = {
    "run, bus from the config": lambda config: ["run", config],
    "run, -i virtual": lambda config: ["run", config, "-i", "virtual", "-c", "c"],
    "plan over the target": lambda config: ["plan", "--patches", "4", "--rate", "100"],
    "plan that does not fit": lambda config: ["plan", "--patches", "64", "--rate", "100"],
}
BAD_VALUES = {
    "read-only --json": lambda: ["--json", READ_ONLY],
    "unavailable --cpu": lambda: ["--cpu", _unavailable_cpu()],
}
CASES = [(c, b) for c in COMMANDS for b in BAD_VALUES
         if not (c.startswith("plan") and b.endswith("--cpu"))]  # plan has no --cpu


@pytest.mark.parametrize(("command", "bad"), CASES)
def test_an_error_is_the_only_line_on_stderr(virtual_host: Path, command: str,
                                             bad: str) -> None:
    result = run(*COMMANDS[command](virtual_host), *BAD_VALUES[bad](), "--seconds", "1") \
        if command.startswith("run") else run(*COMMANDS[command](virtual_host),
                                               *BAD_VALUES[bad]())
    refused(result)
    assert result.lines[0].startswith("skin: error: ")
    assert (READ_ONLY if "json" in bad else "--cpu") in result.lines[0]


def test_the_warnings_held_before_an_error_follow_it_at_debug(virtual_host: Path) -> None:
    result = run("run", virtual_host, "--cpu", _unavailable_cpu(), "-vv")
    assert result.code == 1
    error = next(i for i, line in enumerate(result.lines) if "skin: error: --cpu" in line)
    held = [i for i, line in enumerate(result.lines) if "reaches only this process" in line]
    assert held and all(i > error for i in held)
    assert "DEBUG" in result.lines[held[0]]


def test_a_bus_the_user_named_is_not_warned_about(virtual_host: Path) -> None:
    result = run("run", virtual_host, "-i", "virtual", "-c", "c", "--seconds", "1")
    assert result.code == 0 and "only this process" not in result.err


def test_a_virtual_bus_nobody_named_on_the_command_line_is_said(
        tmp_path: Path, virtual_host: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    result = run("run", virtual_host, "--seconds", "1")
    assert result.code == 0
    assert f"the bus virtual (from {virtual_host}) reaches only this process" in result.err
    bare = tmp_path / "bare.toml"
    bare.write_text("[[patches]]\nnode_id = 1\n")
    monkeypatch.setenv("CAN_INTERFACE", "virtual")  # python-can's configuration
    result = run("run", bare, "--seconds", "1")
    assert result.code == 0
    assert "the bus virtual (from python-can's configuration) reaches only this process" \
        in result.err
