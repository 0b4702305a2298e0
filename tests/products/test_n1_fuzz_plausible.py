"""Plausibility-aware fuzz test of the N1 reader and ``info``.

Where ``test_n1_fuzz.py`` flips random bytes, this mutator builds files that pass the structural
checks but lie: impossible physical values in the tie points and the scaling factors, header
integers beyond int64, a header field widened by one byte (every offset shifts), huge record
counts with consistent sizes in sparse files, absurd record times. It runs in a subprocess so
that the test can measure the peak memory (``resource.getrusage``) and stop a hang (timeout).
Every mutant must be read, described (``meris-ortho info``'s text) and touched without anything
but N1FormatError escaping.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

MUTATIONS = 400
#: peak resident memory the whole run may reach (a real product's reader needs a few MB)
PEAK_MB = 400
TIMEOUT_S = 240


def _mutate(rng, data, product, tmp: Path):
    """One hostile variant of ``data`` written to ``tmp``; returns the kind."""
    from n1_mutants import set_scaling, set_tie_point, sparse_with_counts, tie_records

    from napari_meris_ortho.products.n1.format import (
        DSD_SIZE,
        GADS_DTYPE,
        MPH_SIZE,
        SPH_TEXT_SIZE,
        TIE_POINT_FIELDS,
    )

    kind = ["physical", "scaling", "widened", "sparse", "int64", "times"][rng.integers(0, 6)]
    if kind == "physical":
        field = TIE_POINT_FIELDS[rng.integers(0, len(TIE_POINT_FIELDS))]
        info = np.iinfo(np.dtype(field.dtype))
        records, _ = tie_records(data, product)
        shape = records[field.name].shape[1:]
        where = (int(rng.integers(0, len(records))), int(rng.integers(0, shape[0])))
        everywhere = rng.random() < 0.3
        raw = int(rng.integers(info.min, info.max, dtype=np.int64, endpoint=True))
        data = set_tie_point(data, product, field.name, raw, None if everywhere else where)
    elif kind == "scaling":
        names = [n for n in GADS_DTYPE.names if GADS_DTYPE[n].kind == "f"]
        name = names[rng.integers(0, len(names))]
        value = rng.choice([0.0, -1.0, np.inf, -np.inf, np.nan, 3e38, 1e-38,
                            float(rng.normal() * 10.0 ** rng.integers(-10, 30))])  # fmt: skip
        index = int(rng.integers(0, 15)) if GADS_DTYPE[name].shape else None
        data = set_scaling(data, product, name, np.float32(value), index)
    elif kind == "widened":  # one byte more inside a header line: everything after shifts
        lines_end = MPH_SIZE + SPH_TEXT_SIZE + 30 * DSD_SIZE
        at = int(rng.integers(0, lines_end))
        while data[at : at + 1] in (b"\n", b"="):
            at += 1
        data = data[:at] + bytes([data[at]]) + data[at:]
    elif kind == "sparse":
        exponent = rng.uniform(3, 9)
        claim = int(10**exponent)
        which = rng.integers(0, 3)
        try:
            return kind, sparse_with_counts(
                tmp, data, product,
                tie_lines=claim if which in (0, 2) else None,
                height=claim if which in (1, 2) else None,
            )  # fmt: skip
        except OSError:  # the file system refuses a file that large: nothing to test
            return "skipped", None
    elif kind == "int64":  # a run of header digits replaced by 19..20 nines
        header = data[: MPH_SIZE + SPH_TEXT_SIZE + 30 * DSD_SIZE]
        starts = [i for i in range(1, len(header)) if header[i - 1 : i] == b"+"]
        at = starts[rng.integers(0, len(starts))]
        end = at
        while data[end : end + 1].isdigit():
            end += 1
        width = end - at
        data = data[:at] + b"9" * width + data[end:]
    else:  # record times: days beyond any plausible date
        records, offset = tie_records(data, product)
        records["days"][rng.integers(0, len(records))] = rng.integers(-(2**31), 2**31 - 1)
        data = data[:offset] + records.tobytes() + data[offset + records.nbytes :]
    tmp.write_bytes(data)
    return kind, tmp


def _exercise(path) -> None:
    """Read, describe (``info``) and touch a product the way the commands do."""
    from napari_meris_ortho._commands.info import describe
    from napari_meris_ortho.products.n1 import read_product

    product = read_product(path)
    describe(product)
    for band in (1, 15):
        product.radiance(band, lines=slice(0, 8))
    product.flags[:8].sum()


def _reset_peak_memory() -> None:
    """Forget the peak resident size inherited from the parent (Linux keeps it across fork
    and exec): ``5`` in /proc/self/clear_refs resets VmHWM."""
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")


def _peak_memory_mb() -> float:
    """VmHWM of /proc/self/status: the peak resident size since the reset."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    raise AssertionError("no VmHWM in /proc/self/status")


def fuzz(root: Path, n: int) -> dict:
    import warnings

    from n1_samples import sample_inputs

    from napari_meris_ortho.errors import N1FormatError
    from napari_meris_ortho.products.n1 import read_product, write_product

    rng = np.random.default_rng(15)
    outcomes: dict[str, dict[str, int]] = {}
    goods = [
        write_product(root / "rr.N1", **sample_inputs("MER_RR__1P", 40, 33)),
        write_product(root / "fr.N1", **sample_inputs("MER_FR__1P", 130, 129, seed=3)),
    ]
    for good in goods:
        _exercise(good)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow or invalid-value RuntimeWarning either
        for i in range(n):
            good = goods[i % 2]
            data = good.read_bytes()
            kind, path = _mutate(rng, data, read_product(good), root / f"mutant{i % 2}.N1")
            counts = outcomes.setdefault(kind, {"ok": 0, "error": 0})
            if path is None:
                continue
            try:
                _exercise(path)
            except N1FormatError as exc:
                assert str(exc).startswith(str(path)) and "\n" not in str(exc), exc
                counts["error"] += 1
            except Exception as exc:  # the point of the test: nothing else may escape
                raise AssertionError(f"mutation {i} ({kind}) raised {exc!r}") from exc
            else:
                counts["ok"] += 1
            path.unlink()
    return {"outcomes": outcomes, "peak_mb": _peak_memory_mb()}


@pytest.mark.timeout(TIMEOUT_S + 30)
def test_plausibility_fuzz_clean_errors_bounded_memory_no_hang(tmp_path):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.run(
        [sys.executable, __file__, str(tmp_path), str(MUTATIONS)],
        capture_output=True, text=True, timeout=TIMEOUT_S, env=env,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout.splitlines()[-1])
    outcomes = result["outcomes"]
    # every kind was tried, and every plausibility kind was refused at least once
    for kind in ("physical", "scaling", "widened", "sparse", "int64", "times"):
        assert outcomes[kind]["error"] > 0, outcomes
    assert sum(o["ok"] + o["error"] for o in outcomes.values()) > MUTATIONS * 0.9
    assert result["peak_mb"] < PEAK_MB, result


if __name__ == "__main__":
    _reset_peak_memory()
    print(json.dumps(fuzz(Path(sys.argv[1]), int(sys.argv[2]))))
