"""Progress reporting shared by the CLI (tqdm) and napari (napari.utils.progress).

Long functions take ``progress: ProgressCallback | None``; they call it as
``progress(done, total)`` with monotonically growing ``done``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

ProgressCallback = Callable[[int, int], None]


@contextmanager
def tqdm_progress(desc: str, enabled: bool = True, unit: str = "steps"
                  ) -> Iterator[ProgressCallback]:
    """A ProgressCallback drawing one tqdm bar on stderr, counting ``unit`` (plural: "tiles"),
    shown from the start; nothing when ``enabled`` is false or stderr is not a terminal (no
    carriage-return fragments in logs and pipes). Log lines close the bar first (``stages``)."""
    with stages(enabled) as bars:
        bars.show(desc)
        yield bars.stage(desc, unit)


class Stages:
    """One tqdm bar per stage of a run, on stderr, one stage at a time (``stages`` below).

    ``stage(desc, unit, total)`` returns the ProgressCallback of a stage; its first call
    closes the previous stage's bar and opens its own, so a bar names what is being done
    (reading, locating, writing band k of n) and counts in that stage's units. A stage with
    no total yet shows its name and the time spent, from the start. Any log record closes
    the bar first, so a log line never starts on a bar's line; the next call draws the bar
    again below it.
    """

    def __init__(self, enabled: bool) -> None:
        from ._terminal import stderr_is_terminal

        self.enabled = enabled and stderr_is_terminal()
        self._bar: Any = None
        self._stage: list[Any] | None = None  # desc, unit, done, total

    def stage(self, desc: str, unit: str, total: int | None = None,
              describe: Callable[[int, int], str] | None = None,
              count: Callable[[int, int], tuple[int, int]] | None = None
              ) -> ProgressCallback:
        """The callback of a stage counting ``unit`` (plural: "rows"); ``count(done, total)``
        turns the engine's counts into the stage's, ``describe(done, total)`` words the stage
        from its counts."""
        state = [desc, unit, 0, total]

        def update(done: int, total: int) -> None:
            if count is not None:
                done, total = count(done, total)
            state[2], state[3] = done, total
            if describe is not None:
                state[0] = describe(done, total)
            self._draw(state)

        return update

    def show(self, desc: str) -> None:
        """Open a stage with no count yet: its name and the time spent."""
        self._draw([desc, "", 0, None])

    def _draw(self, state: list[Any]) -> None:
        if not self.enabled:
            return
        if self._stage is not state:
            self.close()
            self._stage = state
        desc, unit, done, total = state
        if self._bar is None:
            from tqdm import tqdm

            fmt = ("{desc} [{elapsed}]" if total is None else  # counts, no rate: units a
                   "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} " + unit  # user reads
                   + " [{elapsed}<{remaining}]")
            self._bar = tqdm(desc=desc, unit=unit, total=total, leave=False,
                             dynamic_ncols=True, bar_format=fmt)
        bar = self._bar
        if bar.desc != desc:
            bar.set_description_str(desc, refresh=False)
        if total is not None and bar.total != total:
            bar.total = total
        bar.n = done
        bar.refresh()

    def close(self) -> None:
        """Close the bar on screen (its stage goes on: a later call draws it again)."""
        if self._bar is not None:
            bar, self._bar = self._bar, None
            bar.close()

    def filter(self, record: logging.LogRecord) -> bool:
        """A logging filter: the bar closed before the record is printed."""
        self.close()
        return True


@contextmanager
def stages(enabled: bool = True) -> Iterator[Stages]:
    """The ``Stages`` of a CLI run: bars drawn only when ``enabled`` and stderr is a
    terminal, closed before every log line (a filter on the root logger's handlers) and at
    the end."""
    run = Stages(enabled)
    handlers = list(logging.getLogger().handlers) if run.enabled else []
    for h in handlers:
        h.addFilter(run.filter)
    try:
        yield run
    finally:
        run.close()
        run._stage = None
        for h in handlers:
            h.removeFilter(run.filter)
