"""The heartbeat monitor tells the target's silence from the host's own pause (issue 23).

After SIGSTOP/SIGCONT the heartbeats that waited in the host's socket may carry the time they were read, not the
time they came, so the gap between the last heartbeat before the pause and the first after it spans the pause."""

from __future__ import annotations

from host.session import Monitor

STATUS = {"State": 2, "FaultBits": 0, "ModelId": 1}


def _beats(monitor: Monitor, times: list[float]) -> None:
    for t in times:
        monitor.status(STATUS, t)


def test_a_gap_that_spans_a_host_pause_is_not_a_heartbeat_loss():
    monitor = Monitor(heartbeat_timeout_s=0.5)
    _beats(monitor, [100.0, 100.1])
    monitor.host_was_paused(2.0, now_s=102.12)      # stopped from 100.12 to 102.12
    _beats(monitor, [102.121] * 20 + [102.2])       # the 20 beats that waited, all stamped when read
    assert monitor.heartbeat_losses == 0
    assert monitor.max_gap_s < 0.1


def test_a_real_silence_is_still_a_loss_beside_a_pause():
    monitor = Monitor(heartbeat_timeout_s=0.5)
    _beats(monitor, [100.0])
    monitor.host_was_paused(0.3, now_s=100.4)       # the host was away 0.3 s of a 2 s silence
    _beats(monitor, [102.0])
    assert monitor.heartbeat_losses == 1
    assert 1.6 < monitor.max_gap_s < 1.8


def test_overlapping_pause_windows_are_counted_once():
    monitor = Monitor(heartbeat_timeout_s=0.5)
    monitor.host_was_paused(2.0, now_s=102.0)
    monitor.host_was_paused(2.0, now_s=102.01)      # the same pause, noted again when caught up with
    assert monitor.host_paused_s == [[100.0, 102.01]]
    _beats(monitor, [99.9, 102.2])
    assert monitor.heartbeat_losses == 0
