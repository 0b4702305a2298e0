"""synthesize: MERSYN use cases 1 and 2 into a synthesis store (the run is ``run.Synthesis``)."""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .._atomic import check_writable_dir
from ..errors import OptionsError, OutputError
from ..options import MergeRule, OrthoOptions, StoreCodec, check_bands, choices, parse
from ..progress import ProgressCallback
from . import store as st

if TYPE_CHECKING:
    from ..dem.base import DemSource
    from ..geometry.grid import OutputGrid
from .reading import is_synthesis, open_synthesis
from .reports import SynthesisResult
from .tiling import ALL_BANDS, BLOCK, DEFAULT_TILE, check_new_grid_size

log = logging.getLogger("napari_meris_ortho.synthesis")

ALGORITHMS = tuple(choices(MergeRule))


# --------------------------------------------------------------------------- synthesize


def synthesize(products: Sequence[str | os.PathLike[str]], out: str | os.PathLike[str], *,
               algorithm: str | None = None, input: str | os.PathLike[str] | None = None,
               grid: OutputGrid | None = None, crs: Any = None,
               pixel_size: float | None = None,
               dems: Sequence[DemSource | str | os.PathLike[str]] = (),
               options: OrthoOptions | None = None,
               bands: Sequence[int] | None = None, reject_bright: bool = False,
               tile: int = DEFAULT_TILE, progress: ProgressCallback | None = None,
               workers: int = 0, scheduler: str | None = None,
               max_pixels: int | None = None, codec: StoreCodec | str | None = None,
               keep: int | None = None, merged: ProgressCallback | None = None,
               **modes: Any) -> SynthesisResult:
    """Orthorectify ``products`` onto the synthesis grid and merge them (section 3.1 use cases
    1-2, Appendix C) into the synthesis store ``out``: one Icechunk commit.

    A new synthesis (no ``input``) takes ``grid``, or the footprint of the earliest readable
    product (sensing time, then name; with ``crs``/``pixel_size``; ``crs`` "utm": its UTM
    zone), and ``bands`` (default all 15). With ``input`` (may equal ``out``: update in place;
    else ``input`` is copied to ``out`` first), grid and bands come from the input synthesis;
    giving grid options or bands too is refused as MERSYN refuses them. A product that cannot
    be read or orthorectified is reported in ``result.failed`` and skipped; one already in the
    synthesis in ``result.skipped``.

    ``workers``: 0 runs the tasks in this process, N > 0 on an embedded LocalCluster of N
    worker processes; ``scheduler``: address of an existing dask scheduler (the store path and
    the products must then be on storage every worker sees: absolute paths). ``progress(done,
    total)`` is called with 0 done before the first task, then after each task; an exception
    raised by it cancels the run (nothing is committed). ``merged(k, n)``: the products whose
    every tile is merged, of the ``n`` products the run merges (called with 0 first, then as
    each product's last tile is written). ``options`` (``OrthoOptions``) and/or
    its fields as keywords (``modes``:
    ``elevation``, ``sampling``, ``geolocation``, ``parallax``, ``tolerance``, ``method``; as
    ``orthorectify``, checked by ``OrthoOptions.of``): how each product is orthorectified
    (geolocation "pixel": the products' per-pixel geolocation, a product without one fails);
    the bands are the synthesis's (``bands``), not the options'.
    ``max_pixels``: largest grid of a new synthesis (default: ``tiling.MAX_GRID_CHUNKS``
    chunks per layer, and the tiles the run writes must fit, uncompressed, in the free space of
    the store's file system; with ``max_pixels`` the free space is not checked); a larger one
    is an OptionsError. ``codec``
    (``StoreCodec``): how a new synthesis encodes its bands and NDVI (default zstd alone; an
    update keeps its store's codecs, and giving one with ``input`` is refused). ``keep``: after
    a commit, keep the newest ``keep`` (>= 1) commits of ``out`` and delete what only older ones
    held, still under the run's lock (``prune_synthesis``; ``result.pruned``).
    """
    from . import run

    out_dir = Path(out)
    if keep is not None:
        _check_keep(keep)
    if "bands" in modes:
        raise OptionsError("give the bands of the synthesis as bands=, not in the options")
    opts = OrthoOptions.of(options, n_dems=len(dems), **modes)
    source_path = _check_options(products, out_dir, algorithm, input, grid, crs, pixel_size,
                                 bands, tile, dems, workers, scheduler, codec)
    if grid is not None and source_path is None:
        check_new_grid_size(grid, len(bands or ALL_BANDS), max_pixels)
    paths = [str(Path(p).absolute()) if scheduler else str(p) for p in products]
    with run.engine(workers, scheduler) as runner:
        created = _make_dir(out_dir)
        with contextlib.ExitStack() as locks:
            locks.enter_context(st.locked(out_dir))
            # from here, under the lock: a run that commits nothing leaves out_dir as it
            # found it (no directory, or the empty directory); the lock file goes with it
            was_empty = not created and not any(out_dir.iterdir())
            try:
                if source_path is not None and source_path.resolve() != out_dir.resolve():
                    locks.enter_context(st.locked(source_path))
                target = _target(out_dir, source_path, algorithm)
                result = run.Synthesis(
                    target, paths, algorithm=algorithm, grid=grid, crs=crs,
                    pixel_size=pixel_size, dems=[str(d) for d in dems], options=opts,
                    bands=bands, reject_bright=reject_bright, tile=tile,
                    progress=progress, merged=merged, max_pixels=max_pixels,
                    codec=parse(StoreCodec, codec or StoreCodec.ZSTD)).run(runner)
            except BaseException:
                _undo(out_dir, created, was_empty)
                raise
            if result.snapshot is None:  # nothing merged: no store
                _undo(out_dir, created, was_empty)
            elif keep is not None:
                result.pruned = _prune(out_dir, keep)
    return result


def prune_synthesis(path: str | os.PathLike[str], keep: int) -> st.Pruned:
    """Keep the newest ``keep`` (>= 1) commits of the synthesis ``path`` and delete the chunk
    versions and metadata that only older commits held (``store.prune``): a season of updates
    costs the disk what the synthesis holds now, not every version of every chunk it held.
    The layers are unchanged; ``synthesis-log`` and ``--at`` reach the commits kept only.
    Under the store's lock: refused while a run uses the store."""
    _check_keep(keep)
    root = Path(path)
    open_synthesis(root)  # one clear message when it is none
    with st.locked(root):
        return _prune(root, keep)


def _check_keep(keep: Any) -> None:
    if isinstance(keep, bool) or not isinstance(keep, int) or keep < 1:
        raise OptionsError(f"keep must be a number of commits >= 1, not {keep!r}")


def _prune(root: Path, keep: int) -> st.Pruned:
    """``store.prune`` of the store ``root``, logged; the caller holds its lock."""
    pruned = st.prune(st.open_repository(root), keep)
    log.debug("%s: kept %d commit(s), expired %d, deleted %d object(s), %.1f MB",
              root, pruned.kept, pruned.expired, pruned.files_deleted,
              pruned.bytes_deleted / 1e6)
    return pruned


def _undo(out_dir: Path, created: bool, was_empty: bool) -> None:
    """Under the lock, when a run committed nothing: remove the store directory this run
    created, or empty again the empty directory it was given (a repository without a
    synthesis is no result); a synthesis that is there stays."""
    if is_synthesis(out_dir) or not (created or was_empty):
        return
    if created:
        shutil.rmtree(out_dir, ignore_errors=True)
        return
    for child in out_dir.iterdir():
        if child.is_dir() and not child.is_symlink():
            shutil.rmtree(child, ignore_errors=True)
        else:
            child.unlink(missing_ok=True)


def _make_dir(out_dir: Path) -> bool:
    """Create the store directory if missing; True when this run created it. No check before
    ``mkdir``: another run may create the directory at any moment (then the lock decides)."""
    try:
        out_dir.mkdir()
    except FileExistsError:
        if not out_dir.is_dir():
            raise OutputError(f"{out_dir}: exists and is not a directory") from None
        return False
    except OSError as exc:
        check_writable_dir(out_dir)  # the clear message: no such directory, not writable
        raise OutputError(f"{out_dir}: cannot create the synthesis store ({exc})") from exc
    return True


def _target(out_dir: Path, source_path: Path | None, algorithm: str | None) -> Any:
    """Under the lock: the repository to write and its synthesis (None: a new one). The "is
    there already a synthesis" check of a new synthesis is made here, under the lock."""
    from .run import Target

    if source_path is None:
        if st.is_repository(out_dir):
            if is_synthesis(out_dir):
                raise OptionsError(f"{out_dir}: already holds a synthesis; pass it as the input "
                                   "synthesis to update it, or choose another output store")
            return Target(out_dir, st.open_repository(out_dir), None)  # left by a killed run
        if (out_dir / st.OLD_MANIFEST).is_file():
            st.open_repository(out_dir)  # raises: old format
        if any(out_dir.iterdir()):
            raise OptionsError(f"{out_dir}: not empty and not a synthesis store")
        return Target(out_dir, st.create_repository(out_dir), None)
    source = open_synthesis(source_path)
    if algorithm is not None and algorithm != source.algorithm:
        raise OptionsError(f"{source_path}: is a {source.algorithm} synthesis, cannot update "
                           f"it with {algorithm}")
    if source_path.resolve() == out_dir.resolve():
        return Target(out_dir, source.repo, source)
    if any(out_dir.iterdir()):
        raise OptionsError(f"{out_dir}: already holds another synthesis or files")
    _copy_store(source_path, out_dir)
    return Target(out_dir, st.open_repository(out_dir), open_synthesis(out_dir))


def _copy_store(source: Path, out_dir: Path) -> None:
    """Copy the repository ``source`` into the empty ``out_dir`` (all its history)."""
    try:
        for entry in source.iterdir():
            if entry.is_dir():
                shutil.copytree(entry, out_dir / entry.name)
            else:
                shutil.copy2(entry, out_dir / entry.name)
    except OSError as exc:
        for entry in out_dir.iterdir():
            shutil.rmtree(entry, ignore_errors=True)
        raise OutputError(f"{out_dir}: cannot copy the input synthesis ({exc})") from exc


def _check_dems(dems: Sequence[Any]) -> None:
    """Open the DEM entries once before any product is read (a bad one is exit code 2, not a
    failure of every product)."""
    if dems:
        from ..dem.stack import DemStack

        DemStack([d for d in dems if not hasattr(d, "sample")]).close()


def _check_not_an_input(out_dir: Path, products: Sequence[Any], input: Any,
                        dems: Sequence[Any]) -> None:
    """The store is no input product or DEM, nor inside one (a ``.SEN3`` directory, a tile
    directory), nor inside the input synthesis it would be copied from."""
    from .._atomic import check_distinct, same_file
    from ..dem.geoid import split_datum

    sources = [] if input is None or same_file(input, out_dir) else [Path(input)]
    check_distinct({"output store": out_dir},
                   {"input product": [Path(p) for p in products], "input synthesis": sources,
                    "DEM": [split_datum(str(d))[0] for d in dems
                            if isinstance(d, str | os.PathLike)]})


def _check_options(products: Sequence[Any], out_dir: Path, algorithm: str | None,
                   input: Any, grid: OutputGrid | None, crs: Any, pixel_size: float | None,
                   bands: Sequence[int] | None, tile: int, dems: Sequence[Any],
                   workers: int, scheduler: str | None, codec: Any = None) -> Path | None:
    """MERSYN's parameter consistency checks (Appendix C), before any work."""
    if algorithm is not None:
        parse(MergeRule, algorithm)
    if not products:
        raise OptionsError("no MERIS product given")
    if tile < BLOCK or tile % BLOCK:
        raise OptionsError(f"tile size {tile}: must be a positive multiple of {BLOCK}")
    if workers < 0:
        raise OptionsError(f"workers {workers}: must be >= 0 (0: in this process)")
    if scheduler is not None and not out_dir.is_absolute():
        raise OptionsError(f"{out_dir}: with a dask scheduler the store must be on storage "
                           "every worker sees: give an absolute path")
    if bands is not None:
        check_bands(bands)
    if pixel_size is not None and not pixel_size > 0:
        raise OptionsError(f"pixel size {pixel_size}: must be positive")
    if crs is not None:
        from ..geometry.grid import is_footprint_utm, parse_crs

        if not is_footprint_utm(crs):  # "utm": the first product's zone
            parse_crs(crs)
    _check_dems(dems)
    if codec is not None:
        parse(StoreCodec, codec)
    if input is None:
        _check_not_an_input(out_dir, products, input, dems)
        return None
    if grid is not None or crs is not None or pixel_size is not None or bands is not None:
        raise OptionsError("when an input synthesis is given, the grid (CRS, extent, pixel "
                           "size) and the bands come from it and shall not be given")
    if codec is not None:
        raise OptionsError("when an input synthesis is given, its layers keep their codec: "
                           "give the store codec for a new synthesis only")
    source = open_synthesis(input)  # refuse a non-synthesis early (again under the lock)
    if algorithm is not None and algorithm != source.algorithm:
        raise OptionsError(f"{input}: is a {source.algorithm} synthesis, cannot update it "
                           f"with {algorithm}")
    _check_not_an_input(out_dir, products, input, dems)
    return Path(input)
