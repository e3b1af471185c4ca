"""SIGTERM and SIGHUP end a command as Ctrl-C does; a finite command leaves nothing half-written."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import numpy as np
import pytest

from skin.cli import main
from skin.commands.common.signals import Stopped, stop_signals_interrupt, until_stopped
from tests.support.rigs.waiting import holds_for, wait_until


def _signal_self(sig: signal.Signals) -> None:
    os.kill(os.getpid(), sig)  # the handler runs in the main thread, while this waits
    wait_until(lambda: False, what=f"{sig.name} interrupting")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_a_stop_signal_interrupts_once_and_the_old_handler_comes_back(
        sig: signal.Signals) -> None:
    seen: list[int] = []
    previous = signal.signal(sig, lambda signum, frame: seen.append(signum))
    try:
        with stop_signals_interrupt():
            with pytest.raises(Stopped) as info:
                _signal_self(sig)
            assert isinstance(info.value, KeyboardInterrupt) and info.value.signal == sig
            os.kill(os.getpid(), sig)  # a second one does not cut the clean stop short
            holds_for(lambda: seen == [], 0.05, what="a second signal ignored")
        assert seen == []
        os.kill(os.getpid(), sig)
        wait_until(lambda: seen == [sig], what="the handler from before is back")
    finally:
        signal.signal(sig, previous)


def test_until_stopped_names_the_signal_and_goes_on() -> None:
    with until_stopped() as by_ctrl_c:
        raise KeyboardInterrupt
    assert by_ctrl_c.signal == "SIGINT"
    with stop_signals_interrupt(), until_stopped() as by_sighup:
        _signal_self(signal.SIGHUP)
    assert by_sighup.signal == "SIGHUP"
    with until_stopped() as not_stopped:
        pass
    assert not_stopped.signal is None
    with pytest.raises(ValueError, match="not a stop"), until_stopped():
        raise ValueError("an error is not a stop")


def test_sigterm_in_a_finite_command_exits_130_and_leaves_no_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    real = np.lib.format.write_array

    def stopped_halfway(*args: object, **kwargs: object) -> None:
        real(*args, **kwargs)  # type: ignore[arg-type]
        _signal_self(signal.SIGTERM)  # as systemd stops it, half-way through the file

    monkeypatch.setattr(np.lib.format, "write_array", stopped_halfway)
    code = main(["sim", "dataset", "paper", "-n", "3", "-o", str(tmp_path / "d.npz")])
    assert code == 130
    assert capsys.readouterr().err == "skin: interrupted (SIGTERM)\n"
    assert list(tmp_path.iterdir()) == []  # neither d.npz nor its temporary file


def test_sigterm_while_a_long_running_command_starts_is_still_a_clean_stop(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """docs/cli.md: stopping is how `skin sim run` (and the other long-running commands)
    end, exit status 0, whatever they are doing: while they set up too."""
    import skin.commands.sim.run as sim_run

    real = sim_run.plan_for

    def stopped_while_planning(*args: object, **kwargs: object) -> object:
        _signal_self(signal.SIGTERM)  # as systemd stops it before it serves
        return real(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(sim_run, "plan_for", stopped_while_planning)
    code = main(["sim", "run", "indenter", "-i", "virtual", "-c", "signals-start",
                 "--seconds", "1", "--json", str(tmp_path / "run.json")])
    assert code == 0
    assert capsys.readouterr().err.endswith("skin: stopped (SIGTERM)\n")
    assert list(tmp_path.iterdir()) == []  # nothing half-written


def test_a_stop_signal_the_process_was_started_ignoring_stays_ignored() -> None:
    """``nohup skin run &`` outlives its terminal: nohup's ignored SIGHUP is not a stop."""
    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with stop_signals_interrupt():
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
            assert signal.getsignal(signal.SIGTERM) is not signal.SIG_IGN  # still a stop
            os.kill(os.getpid(), signal.SIGHUP)
            holds_for(lambda: True, 0.05, what="an ignored SIGHUP changing nothing")
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, previous)
