"""Issue 39: while the cluster has no worker the driver says so, naming the scheduler, at once and then every
NO_WORKER_NOTICE_S, says when one joins, and gives up after NO_WORKER_LIMIT_S with one sentence."""

from __future__ import annotations

import pytest

from bench.campaign.once import NO_WORKER_LIMIT_S, NO_WORKER_NOTICE_S, NoWorkerError, WorkerWatch

WHERE, ADDRESS = "the scheduler at tcp://10.0.0.5:8786", "tcp://10.0.0.5:8786"


def watch_at(times: list[float]) -> tuple[WorkerWatch, list[str]]:
    said: list[str] = []
    clock = iter(times)
    return WorkerWatch(WHERE, ADDRESS, notice=said.append, clock=lambda: next(clock)), said


def test_no_worker_is_said_at_once_then_every_interval_and_a_worker_joining_too():
    step = NO_WORKER_NOTICE_S / 3
    times = [0.0] + [10.0 + step * i for i in range(7)] + [40.0]
    watch, said = watch_at(times)
    watch.check(2, 5)                               # workers there: nothing said
    for _ in range(7):                              # 0, 1/3, ... 2 intervals after the workers went
        watch.check(0, 5)
    assert said == [f"no Dask worker is available on {WHERE} ({seconds:.0f} s so far, 5 task(s) waiting); waiting "
                    f"up to {NO_WORKER_LIMIT_S:.0f} s for one to join (`dask worker {ADDRESS}`)"
                    for seconds in (0, NO_WORKER_NOTICE_S, 2 * NO_WORKER_NOTICE_S)]
    assert watch.waiting
    watch.check(1, 3)
    assert said[-1] == f"a Dask worker joined {WHERE}; going on" and not watch.waiting


def test_the_driver_gives_up_after_the_limit_with_one_sentence():
    watch, said = watch_at([0.0, NO_WORKER_LIMIT_S - 0.1, NO_WORKER_LIMIT_S + 0.1])
    watch.check(0, 2)
    watch.check(0, 2)
    with pytest.raises(NoWorkerError) as caught:
        watch.check(0, 2)
    assert str(caught.value) == (f"{WHERE} has had no worker for {NO_WORKER_LIMIT_S:.0f} s, 2 task(s) not done; "
                                 f"start one (`dask worker {ADDRESS}`) and run again with --resume")
    assert len(said) == 2                           # each check below the limit an interval apart said so
