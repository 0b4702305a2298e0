"""Pruning a synthesis store's history (``prune_synthesis``, ``meris-ortho synthesis-prune``):
the layers stay, the chunk versions only older commits held are deleted, updates after a prune
give the bytes of updates without one, and the lock keeps it away from a running synthesis."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from napari_meris_ortho.cli import main
from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.synthesis import store as st
from napari_meris_ortho.synthesis.api import prune_synthesis, synthesize
from napari_meris_ortho.synthesis.reading import open_synthesis
from test_synthesis import BANDS, GRID, layers, scene_product

RUN = dict(tile=256, elevation="tiepoints")


@pytest.fixture(scope="module")
def products() -> list[str]:
    return [scene_product({"fraction": 0.4, "scale_km": 12.0, "seed": 10 * k})
            for k in (1, 2, 3)] + [scene_product()]


def disk_bytes(root: Path) -> int:
    return sum(p.stat().st_size for p in root.rglob("*") if p.is_file())


def season(products: list[str], out: Path) -> None:
    """One commit per product: a new synthesis, then updates."""
    synthesize(products[:1], out, grid=GRID, bands=BANDS, algorithm="max-ndvi", **RUN)
    for path in products[1:]:
        synthesize([path], out, input=out, **RUN)


@pytest.mark.slow
def test_prune_keeps_the_layers_and_frees_the_old_chunk_versions(products, tmp_path) -> None:
    out, twin = tmp_path / "pruned", tmp_path / "twin"
    season(products[:3], out)
    season(products[:3], twin)
    before, commits = layers(out), [c.snapshot for c in open_synthesis(out).history()]
    sizes = [disk_bytes(out)]
    for keep in (2, 1):
        pruned = prune_synthesis(out, keep)
        assert pruned.kept == keep and pruned.expired == 1
        assert pruned.chunks_deleted > 0 and pruned.bytes_deleted > 0
        assert [c.snapshot for c in open_synthesis(out).history()] == commits[:keep]
        sizes.append(disk_bytes(out))
        assert sizes[-1] < sizes[-2]
        assert sizes[-2] - sizes[-1] >= pruned.bytes_deleted * 0.99  # what it says it freed
        for name, value in layers(out).items():
            assert value.tobytes() == before[name].tobytes(), name
    assert len(open_synthesis(out).products) == 3  # the product table keeps every product
    again = prune_synthesis(out, 1)  # nothing left to free
    assert (again.expired, again.files_deleted) == (0, 0)
    # after the prune: a product merged before is still recognised, and an update gives the
    # bytes the same update gives on the store that kept its history
    assert synthesize(products[:1], out, input=out, **RUN).skipped
    synthesize(products[3:], out, input=out, **RUN)
    synthesize(products[3:], twin, input=twin, **RUN)
    for name, value in layers(out).items():
        assert value.tobytes() == layers(twin)[name].tobytes(), name
    assert len(open_synthesis(out).history()) == 2 and len(open_synthesis(twin).history()) == 4


def test_prune_removes_the_branch_of_a_killed_run(products, tmp_path) -> None:
    """A new synthesis lays its arrays out on a run branch; a run killed before its commit
    leaves the branch and its chunks. The prune deletes both; main is untouched."""
    out = tmp_path / "store"
    season(products[:1], out)
    before = layers(out)
    repo = st.open_repository(out)
    repo.create_branch(f"{st.RUN_BRANCH_PREFIX}killed", repo.lookup_branch(st.BRANCH))
    session = repo.writable_session(f"{st.RUN_BRANCH_PREFIX}killed")
    layer = st.open_layer(session.store, st.band_layer(BANDS[0]))
    layer[:256, :256] = np.random.default_rng(0).integers(1, 60000, (256, 256), np.uint16)
    session.commit("a tile of a run that was killed before its commit")
    pruned = prune_synthesis(out, 5)
    assert pruned.run_branches == 1 and pruned.chunks_deleted >= 1
    assert st.open_repository(out).list_branches() == {st.BRANCH}
    assert (pruned.kept, pruned.expired) == (1, 0)
    for name, value in layers(out).items():
        assert value.tobytes() == before[name].tobytes(), name


def test_prune_is_refused_while_a_run_uses_the_store(products, tmp_path) -> None:
    out = tmp_path / "store"
    season(products[:2], out)
    with st.locked(out), pytest.raises(OptionsError, match="another synthesis run"):
        prune_synthesis(out, 1)
    assert len(open_synthesis(out).history()) == 2
    with pytest.raises(OptionsError, match="keep must be a number of commits >= 1"):
        prune_synthesis(out, 0)
    with pytest.raises(OptionsError):
        prune_synthesis(tmp_path / "none", 1)
    assert not (tmp_path / "none").exists()


def test_synthesis_prune_command(products, tmp_path, capsys) -> None:
    out = tmp_path / "store"
    season(products[:2], out)
    old = open_synthesis(out).history()[1].snapshot
    assert main(["synthesis-log", str(out), "--at", old]) == 0
    capsys.readouterr()
    assert main(["synthesis-prune", str(out), "--keep", "1"]) == 0
    said = capsys.readouterr().out
    assert said.startswith(f"{out}: kept 1 commit(s), expired 1; deleted ") and "MB freed" in said
    assert main(["synthesis-log", str(out)]) == 0
    assert capsys.readouterr().out.count("\nsnapshot ") == 1
    for argv, message in ((["--keep", "0"], "'0' is not a number of commits >= 1"),
                          ([], "the following arguments are required: --keep")):
        with pytest.raises(SystemExit) as exc:
            main(["synthesis-prune", str(out), *argv])
        assert exc.value.code == 2 and message in capsys.readouterr().err
    assert main(["synthesis-log", str(out), "--at", old]) == 2  # the pruned commit
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"meris-ortho: error: {out}: no snapshot '{old}' in the synthesis store "
                   "(its commits: synthesis-log; a pruned commit is gone)"]
    assert main(["synthesis-prune", str(tmp_path / "none"), "--keep", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("meris-ortho: error:")


@pytest.mark.slow
def test_synthesize_keep_prunes_after_its_commit(products, tmp_path, capsys) -> None:
    """``synthesize --keep N``: the update commits, then prunes under the same lock; the
    store ends as an update followed by ``synthesis-prune --keep N`` leaves its twin."""
    out, twin = tmp_path / "kept", tmp_path / "twin"
    season(products[:2], out)
    season(products[:2], twin)
    result = synthesize(products[2:3], out, input=out, keep=1, **RUN)
    assert result.snapshot is not None and result.pruned is not None
    assert (result.pruned.kept, result.pruned.expired) == (1, 2)
    assert result.pruned.bytes_deleted > 0
    synthesize(products[2:3], twin, input=twin, **RUN)
    freed = prune_synthesis(twin, 1)
    # the same objects freed (metadata bytes differ by their ids and times)
    assert (freed.chunks_deleted, freed.files_deleted) == (result.pruned.chunks_deleted,
                                                           result.pruned.files_deleted)
    assert freed.bytes_deleted == pytest.approx(result.pruned.bytes_deleted, rel=1e-3)
    assert [c.snapshot for c in open_synthesis(out).history()] == [result.snapshot]
    for name, value in layers(out).items():
        assert value.tobytes() == layers(twin)[name].tobytes(), name
    assert disk_bytes(out) == pytest.approx(disk_bytes(twin), rel=1e-3)
    # nothing merged (already in the synthesis): no commit, no prune
    again = synthesize(products[2:3], out, input=out, keep=1, **RUN)
    assert again.snapshot is None and again.pruned is None and again.skipped
    # the CLI: --keep after the commit, logged; a bad --keep refused before anything runs
    assert main(["-q", "synthesize", products[3], "--out", str(out), "--input", str(out),
                 "--keep", "2", "--workers", "0", "--elevation", "tiepoints"]) == 0
    assert len(open_synthesis(out).history()) == 2
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        main(["synthesize", products[3], "--out", str(out), "--input", str(out),
              "--keep", "0"])
    assert exc.value.code == 2 and "'0' is not a number of commits >= 1" in capsys.readouterr().err
    with pytest.raises(OptionsError, match="keep must be a number of commits >= 1"):
        synthesize(products[3:], tmp_path / "new", grid=GRID, bands=BANDS, keep=0, **RUN)
    assert not (tmp_path / "new").exists()
