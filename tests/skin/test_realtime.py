"""``--realtime``: the host's threads under SCHED_FIFO where the process may have it, one
warning and normal priority where it may not."""

from __future__ import annotations

import logging
import os
import threading

import pytest

from skin.commands.common.realtime import realtime


def _policy_of_a_new_thread() -> int:
    seen: list[int] = []
    thread = threading.Thread(target=lambda: seen.append(os.sched_getscheduler(0)))
    thread.start()
    thread.join()
    return seen[0]


def test_threads_started_under_realtime_run_fifo_and_the_caller_is_restored() -> None:
    before = os.sched_getscheduler(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        os.sched_setscheduler(0, before, os.sched_param(0))
    except PermissionError:
        pytest.skip("this process may not use SCHED_FIFO (not root, no CAP_SYS_NICE)")
    with realtime(7) as granted:
        assert granted
        assert _policy_of_a_new_thread() == os.SCHED_FIFO
        assert os.sched_getparam(0).sched_priority == 7
    assert os.sched_getscheduler(0) == before
    assert _policy_of_a_new_thread() == before


def test_where_it_is_not_permitted_one_warning_and_normal_priority(
        monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    def refuse(*_args: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    before = os.sched_getscheduler(0)
    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with caplog.at_level(logging.WARNING), realtime(50) as granted:
        assert not granted
        assert os.sched_getscheduler(0) == before
    assert [r.getMessage() for r in caplog.records] == [
        "--realtime 50: not permitted (needs CAP_SYS_NICE, or LimitRTPRIO=50 in the systemd "
        "unit); running at normal priority"]


def test_no_realtime_changes_nothing() -> None:
    before = os.sched_getscheduler(0)
    with realtime(None) as granted:
        assert not granted and os.sched_getscheduler(0) == before
