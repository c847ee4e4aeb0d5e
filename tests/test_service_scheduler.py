"""The worker pool's order (service.workers.pool.Pool): cost first with aging, a lane for cheap jobs,
per-client shares. Jobs here run on threads that wait for the test to release them, so the
order is observed exactly, without timing."""
from __future__ import annotations

import asyncio
import threading

import pytest

from service.workers.pool import Pool, QueueFull, WorkerConfig
from service.workers.protocol import BakeEnvironmentJob, Done


class _Slot:
    def __init__(self, index: int):
        self.index, self.pid, self.jobs, self.restarts = index, None, 0, 0
        self.busy_since = self.op = None
        self.answered = True

    def alive(self) -> bool:
        return True


class GatedPool(Pool):
    """A pool whose workers run a job by recording it and waiting until the test opens its gate."""

    def __init__(self, size: int, **order):
        super().__init__(size, WorkerConfig(cache_dir="unused"), 64, None, "test-pool", **order)
        self.workers = [_Slot(i) for i in range(size)]
        self.started: list[str] = []
        self.gates: dict[str, threading.Event] = {}
        self._lock = threading.Lock()

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._free = list(self.workers)

    def _exchange(self, w, job, deadline):
        name = job.source  # any typed job does: this one carries a name
        with self._lock:
            self.started.append(name)
            gate = self.gates.setdefault(name, threading.Event())
        gate.wait(30)
        return Done(name)

    def open(self, name: str) -> None:
        with self._lock:
            self.gates.setdefault(name, threading.Event()).set()


async def _until(cond, what: str) -> None:
    for _ in range(2000):
        if cond():
            return
        await asyncio.sleep(0.005)
    raise AssertionError(f"never: {what}")


def _submit(pool, name, cost, client=None, expensive=None):
    return asyncio.ensure_future(pool.run(BakeEnvironmentJob(name), deadline=30, cost_ms=cost, client=client,
                                          expensive=expensive))


def test_cheapest_waiting_job_runs_first_and_one_worker_stays_for_cheap_ones():
    async def main():
        pool = GatedPool(2, cheap_ms=1000, client_share=1.0)
        await pool.start()
        big1 = _submit(pool, "big1", 50_000)
        await _until(lambda: pool.started == ["big1"], "big1 starts")
        big2 = _submit(pool, "big2", 50_000)       # expensive: waits, one worker is kept
        mid = _submit(pool, "mid", 900)
        await _until(lambda: pool.started == ["big1", "mid"], "mid takes the cheap lane")
        small = _submit(pool, "small", 100)      # asked first, costs more
        tiny = _submit(pool, "tiny", 5)
        await asyncio.sleep(0.05)
        assert pool.started == ["big1", "mid"]     # both workers busy
        pool.open("mid")
        await _until(lambda: len(pool.started) == 3, "next job")
        assert pool.started[2] == "tiny"           # cheapest first; big2 still may not start
        pool.open("tiny")
        await _until(lambda: len(pool.started) == 4, "next job")
        assert pool.started[3] == "small"
        pool.open("big1")
        await _until(lambda: len(pool.started) == 5, "big2")
        for name in ("small", "big2"):
            pool.open(name)
        assert [await t for t in (big1, big2, mid, tiny, small)] == ["big1", "big2", "mid", "tiny", "small"]
    asyncio.run(main())


def test_a_client_holds_at_most_its_share_of_the_workers():
    async def main():
        pool = GatedPool(4, cheap_ms=1000, client_share=0.5)  # 2 workers each; 3 for expensive work
        await pool.start()
        hog = [_submit(pool, f"a{i}", 10_000, client="a") for i in range(4)]
        await _until(lambda: len(pool.started) == 2, "two of a's jobs")
        await asyncio.sleep(0.05)
        assert sorted(pool.started) == ["a0", "a1"]
        other = _submit(pool, "b0", 20_000, client="b")  # costlier, but b holds nothing yet
        await _until(lambda: "b0" in pool.started, "b's job starts beside a's")
        for name in ("a0", "a1", "a2", "a3", "b0"):
            pool.open(name)
        await asyncio.gather(*hog, other)
    asyncio.run(main())


def test_aging_lets_an_expensive_job_pass_a_stream_of_cheap_ones():
    async def main():
        pool = GatedPool(1, cheap_ms=1000)
        pool.AGING_MS_PER_S = 1e6  # a waited second outweighs any cost difference here
        await pool.start()
        first = _submit(pool, "first", 1)
        await _until(lambda: pool.started == ["first"], "first")
        big = _submit(pool, "big", 5_000)
        await asyncio.sleep(0.1)
        cheap = _submit(pool, "cheap", 1)
        pool.open("first")
        await _until(lambda: len(pool.started) == 2, "next")
        assert pool.started[1] == "big"
        pool.open("big")
        pool.open("cheap")
        await asyncio.gather(first, big, cheap)
    asyncio.run(main())


def test_queue_share_per_client_answers_queue_full():
    async def main():
        pool = GatedPool(1, client_share=0.5)
        pool.max_queue, pool.client_queue = 4, 2
        await pool.start()
        jobs = [_submit(pool, f"a{i}", 1, client="a") for i in range(2)]
        await asyncio.sleep(0.02)
        with pytest.raises(QueueFull, match="your share"):
            await pool.run(BakeEnvironmentJob("a2"), deadline=30, client="a")
        b = _submit(pool, "b0", 1, client="b")  # another client still gets in
        for name in ("a0", "a1", "b0"):
            pool.open(name)
        await asyncio.gather(*jobs, b)
    asyncio.run(main())


def test_a_cancelled_waiting_job_gives_nothing_away():
    async def main():
        pool = GatedPool(1)
        await pool.start()
        first = _submit(pool, "first", 1)
        await _until(lambda: pool.started == ["first"], "first")
        gone = _submit(pool, "gone", 1)
        await asyncio.sleep(0.02)
        gone.cancel()
        after = _submit(pool, "after", 1)
        pool.open("first")
        await _until(lambda: len(pool.started) == 2, "after")
        assert pool.started == ["first", "after"]
        pool.open("after")
        await asyncio.gather(first, after)
        assert pool.pending == 0 and len(pool._free) == 1
    asyncio.run(main())


def test_clients_take_turns_for_cheap_workers():
    async def main():
        pool = GatedPool(2, cheap_ms=1000)
        await pool.start()
        a = [_submit(pool, f"a{i}", 10, client="a") for i in range(4)]  # a floods cheap jobs
        await _until(lambda: len(pool.started) == 2, "a0, a1")
        b = _submit(pool, "b0", 50, client="b")  # asked later, costs more, but b runs nothing
        pool.open("a0")
        await _until(lambda: len(pool.started) == 3, "next")
        assert pool.started[2] == "b0"
        for name in ("a1", "a2", "a3", "b0"):
            pool.open(name)
        await asyncio.gather(*a, b)
    asyncio.run(main())
