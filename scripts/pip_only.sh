#!/usr/bin/env bash
# pip-only install, as a napari user gets the plugin: build the wheel and sdist, install the wheel
# into a fresh virtual environment that sees no system site-packages and no apt data (PROJ's
# grids of Debian's proj-data hidden), then simulate
# fr-small, map it with tie-point heights and with its GeoTIFF DEM, and validate the plugin's
# napari manifest. Prints the time of each step. Needs python3 with venv and pip; no apt package.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
WORK=$(mktemp -d "${TMPDIR:-/tmp}/meris-pip-only.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
t0=$(date +%s)
step() { echo "[pip-only] $(( $(date +%s) - t0 )) s: $*"; }

step "build wheel and sdist"
"$PY" -m venv "$WORK/build"
"$WORK/build/bin/python" -m pip install -q build
"$WORK/build/bin/python" -m build -q --outdir "$WORK/dist" . >/dev/null
ls "$WORK/dist"/*.whl "$WORK/dist"/*.tar.gz >/dev/null

step "install the wheel into a clean venv"
"$PY" -m venv "$WORK/venv"
"$WORK/venv/bin/python" -m pip install -q "$WORK/dist"/*.whl npe2
export PATH="$WORK/venv/bin:$PATH"
unset PYTHONPATH PROJ_LIB PROJ_DATA
# only the wheels' own PROJ data, as on a machine without proj-data: Debian's /usr/share/proj
# (its geoid grid) out of our search path (rasterio and pyproj each use their own proj.db)
export MERIS_ORTHO_PROJ_SYSTEM_DIRS=""
cd "$WORK"
python - <<'EOF'
import napari_meris_ortho, pathlib
assert "site-packages" in napari_meris_ortho.__file__, napari_meris_ortho.__file__
print("installed:", pathlib.Path(napari_meris_ortho.__file__).parent)
EOF

step "meris-ortho sample fr-small"
meris-ortho sample fr-small --out "$WORK/fr-small"
product=$(ls "$WORK"/fr-small/MER_*.N1 | head -1)

step "meris-ortho map: tie-point heights"
meris-ortho map "$product" -o "$WORK/tiepoints.tif" --elevation tiepoints
step "meris-ortho map: GeoTIFF DEM"
meris-ortho map "$product" -o "$WORK/dem.tif" --dem "$WORK/fr-small/dem_truth.tif"
python - "$WORK/tiepoints.tif" "$WORK/dem.tif" <<'EOF'
import sys
import rasterio
for path in sys.argv[1:]:
    with rasterio.open(path) as ds:
        band = ds.read(1)
        assert ds.crs is not None and (band > 0).sum() > 100_000, path
        print(path, ds.width, "x", ds.height, ds.crs.to_string(), "overviews", ds.overviews(1))
EOF

step "napari manifest validation"
npe2 validate napari-meris-ortho
step "done"
