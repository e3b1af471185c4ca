"""The shared daemon thread with a stop flag (canbus.worker)."""

from __future__ import annotations

import threading

from canbus.worker import Worker


def test_a_worker_runs_its_target_on_a_named_daemon_thread_until_stopped() -> None:
    rounds = 0
    seen: list[threading.Thread] = []
    first = threading.Event()

    def target() -> None:
        nonlocal rounds
        seen.append(threading.current_thread())
        while not worker.stopping.wait(0.001):
            rounds += 1
            first.set()

    worker = Worker(target, "test-worker")
    assert not worker.running
    worker.start()
    assert worker.running
    assert first.wait(5.0)
    worker.stop()
    assert not worker.running and worker.stopping.is_set()
    assert not seen[0].is_alive()  # stop() joined it: no round after it returned
    assert rounds >= 1 and seen[0].name == "test-worker" and seen[0].daemon


def test_a_worker_starts_again_after_a_stop_and_a_stop_without_start_is_harmless() -> None:
    runs: list[str] = []

    def target() -> None:
        runs.append(threading.current_thread().name)
        worker.stopping.wait()

    worker = Worker(target, "again")
    worker.stop()  # never started
    for _ in range(2):
        worker.start()
        assert not worker.stopping.is_set()
        worker.stop()
    worker.stop()  # stopped already
    assert runs == ["again", "again"]
