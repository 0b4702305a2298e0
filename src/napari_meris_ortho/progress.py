"""Progress reporting shared by the CLI (tqdm) and napari (napari.utils.progress).

Long functions take ``progress: ProgressCallback | None``; they call it as
``progress(done, total)`` with monotonically growing ``done``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

ProgressCallback = Callable[[int, int], None]


@contextmanager
def tqdm_progress(desc: str, enabled: bool = True, unit: str = "it") -> Iterator[ProgressCallback]:
    """A ProgressCallback drawing a tqdm bar on stderr (nothing when ``enabled`` is false or
    stderr is not a terminal: no carriage-return fragments in logs and pipes)."""
    from ._terminal import stderr_is_terminal

    if not (enabled and stderr_is_terminal()):
        yield lambda done, total: None
        return
    from tqdm import tqdm

    bar = tqdm(desc=desc, unit=unit, leave=False, dynamic_ncols=True)

    def update(done: int, total: int) -> None:
        if bar.total != total:
            bar.total = total
        bar.n = done
        bar.refresh()

    try:
        yield update
    finally:
        bar.close()
