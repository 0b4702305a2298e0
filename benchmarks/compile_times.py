"""Numba compile times of one CLI run, as a table (first run: use a fresh numba cache).

    NUMBA_CACHE_DIR=/tmp/fresh-nc PYTHONPATH=$PWD/src python benchmarks/compile_times.py \
        -q map <N1> -o /tmp/out.tif --dem <dem>

Registers a ``numba:compile`` event listener, runs ``napari_meris_ortho.cli.main`` in-process
with the given arguments, then prints every compilation: CPU seconds of the compiling thread
including the nested ones (callees compiled on the way), CPU seconds of its own, and the wall
time since start when it ended (CPU time: the machine may be shared).
Top-level compilations (not nested in another) are marked ``*``; their sum is the compile time
of the run. Loading from the cache is not an event (a warm cache prints nothing).
"""

from __future__ import annotations

import sys
import threading
import time

from numba.core import event


class _Listener(event.Listener):
    def __init__(self, t0: float) -> None:
        self.t0 = t0
        # per thread: [thread CPU at start, CPU seconds spent in nested compilations]
        self.stacks: dict[int, list[list[float]]] = {}
        self.rows: list[tuple[float, float, float, int, str]] = []

    def on_start(self, e: event.Event) -> None:
        self.stacks.setdefault(threading.get_ident(), []).append([time.thread_time(), 0.0])

    def on_end(self, e: event.Event) -> None:
        stack = self.stacks[threading.get_ident()]
        start, nested = stack.pop()
        total = time.thread_time() - start
        if stack:
            stack[-1][1] += total
        name = e.data["dispatcher"].py_func.__qualname__
        self.rows.append((total, total - nested, time.perf_counter() - self.t0, len(stack),
                          name))


def main(argv: list[str]) -> None:
    t0 = time.perf_counter()
    listener = _Listener(t0)
    event.register("numba:compile", listener)
    from napari_meris_ortho.cli import main as cli_main

    try:
        cli_main(argv)
    except SystemExit:
        pass
    wall = time.perf_counter() - t0
    print(f"{'incl s':>7} {'self s':>7} {'end s':>6}  kernel (* top level; CPU s, end: wall)")
    top = 0.0
    for total, own, end, depth, name in listener.rows:
        if depth == 0:
            top += total
        print(f"{total:7.2f} {own:7.2f} {end:6.1f}  {'*' if depth == 0 else ' '}"
              f"{'  ' * depth}{name}")
    print(f"compile {top:.2f} CPU s; wall {wall:.2f} s, process CPU {time.process_time():.2f} s")


if __name__ == "__main__":
    main(sys.argv[1:])
