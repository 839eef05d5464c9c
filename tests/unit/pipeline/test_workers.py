"""swim.workers: long-lived worker pools shared by the parallel stages."""

import threading

import pytest

from swim.workers import worker_pool


def test_the_pool_of_a_size_is_made_once_and_its_threads_are_reused():
    pool = worker_pool(2)
    assert worker_pool(2) is pool
    threads = {pool.submit(threading.current_thread).result() for _ in range(20)}  # the Thread objects, held
    assert threads and all(t.name.startswith("swim-worker-2") for t in threads)
    assert len(threads) <= 2, "a pool of 2 must run its tasks on at most 2 threads"
    again = {worker_pool(2).submit(threading.current_thread).result() for _ in range(20)}
    # the pool's two threads serve every call (which of them runs a task is up to the pool: the first calls may all
    # have run on one of them), never a new one
    assert len(threads | again) <= 2, "later calls must run on the same pool's threads, not new ones"

def test_a_worker_may_not_wait_on_the_pools():
    with pytest.raises(RuntimeError, match="deadlock"):
        worker_pool(1).submit(worker_pool, 1).result()


def test_bad_sizes_are_refused():
    with pytest.raises(ValueError, match="n must be >= 1"):
        worker_pool(0)


def test_parallel_map_keeps_the_order_runs_alone_on_one_thread_and_raises_what_a_call_raises():
    from swim.workers import parallel_map

    assert parallel_map(lambda x: x * x, range(50), 2) == [x * x for x in range(50)]
    # one thread (or one item): on the calling thread
    assert set(parallel_map(lambda _: threading.current_thread(), range(5), 1)) == {threading.current_thread()}
    assert parallel_map(lambda _: threading.current_thread(), [0], 4) == [threading.current_thread()]
    workers = set(parallel_map(lambda _: threading.current_thread().name, range(20), 2))
    assert workers and all(name.startswith("swim-worker-2") for name in workers)
    assert parallel_map(lambda x: x, [], 4) == []

    def fail_on_three(x):
        if x == 3:
            raise ValueError("three")
        return x

    with pytest.raises(ValueError, match="three"):
        parallel_map(fail_on_three, range(8), 2)
