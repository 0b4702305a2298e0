"""The cores this process may run on: one count for the default number of synthesis workers
(``meris-ortho synthesize``), and the threads the engine's kernels and the COG writer's
compression may use (``engine.threads``, ``output.cog``): as many as the cores, or fewer when the
environment limits them, as a dask worker's does."""

from __future__ import annotations

import os

#: environment variables limiting the threads of numeric code, first set first: numba's own,
#: then the OpenMP one (a dask nanny sets ``OMP_NUM_THREADS=1`` for its workers:
#: ``distributed.nanny.pre-spawn-environ``, the tasks being the parallelism)
THREAD_LIMITS = ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS")


def usable_cores() -> int:
    """Cores of this process's CPU affinity (a container or ``taskset`` may give fewer than the
    machine has); ``os.cpu_count()`` where there is no affinity; at least 1."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # pragma: no cover - not Linux
        return max(os.cpu_count() or 1, 1)


def thread_limit() -> int | None:
    """The thread count the environment asks for (``THREAD_LIMITS``; the first one set to a
    positive integer), None when none is."""
    for name in THREAD_LIMITS:
        value = os.environ.get(name, "").strip()
        if value.isdigit() and int(value) > 0:
            return int(value)
    return None


def usable_threads() -> int:
    """Threads for the engine's kernels: the usable cores, at most ``thread_limit()``. A dask
    worker of one thread (``--nthreads 1``, and our LocalCluster's ``WORKER_ENV``) so runs its
    task's kernels on one thread instead of every core (two workers on two cores: four busy
    threads)."""
    limit = thread_limit()
    cores = usable_cores()
    return cores if limit is None else min(cores, limit)
