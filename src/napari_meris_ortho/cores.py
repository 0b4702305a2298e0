"""The cores this process may run on: one count for the engine's thread pool
(``engine.threads``), the COG writer's compression threads (``output.cog``) and the default number
of synthesis workers (``meris-ortho synthesize``)."""

from __future__ import annotations

import os


def usable_cores() -> int:
    """Cores of this process's CPU affinity (a container or ``taskset`` may give fewer than the
    machine has); ``os.cpu_count()`` where there is no affinity; at least 1."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # pragma: no cover - not Linux
        return max(os.cpu_count() or 1, 1)
