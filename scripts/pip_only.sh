#!/usr/bin/env bash
# pip-only install, as users get the package: build the wheel and sdist, then
#  (a) the bare wheel (no extra) into a fresh virtual environment that sees no system
#      site-packages and no apt data (PROJ's grids of Debian's proj-data hidden): no napari
#      there; `meris-ortho --version`, simulate fr-small, map it with tie-point heights and
#      with its GeoTIFF DEM;
#  (b) the `napari` extra into the same environment: validate the plugin's napari manifest and
#      open fr-small in a napari viewer under Xvfb (xvfb-run, as `scripts/setup.sh --gui`
#      installs it).
# Prints the time of each step. Needs python3 with venv and pip; no apt package for (a).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
WORK=$(mktemp -d "${TMPDIR:-/tmp}/meris-pip-only.XXXXXX")
trap 'rm -rf "$WORK"' EXIT

t0=$EPOCHREALTIME
t_step=$t0
current=""
times=()
elapsed() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%6.1f", b - a }'; }
# step NAME: ends the current step (prints its time) and starts NAME; `step ""` ends the last
step() {
    local now=$EPOCHREALTIME
    if [[ -n $current ]]; then
        local line
        line="$(elapsed "$t_step" "$now") s  $current"
        times+=("$line")
        echo "[pip-only] $line"
    fi
    current=$1
    t_step=$now
    if [[ -n $current ]]; then echo "[pip-only] -- $current"; fi
}

step "build wheel and sdist"
"$PY" -m venv "$WORK/build"
"$WORK/build/bin/python" -m pip install -q build
"$WORK/build/bin/python" -m build -q --outdir "$WORK/dist" . >/dev/null
ls "$WORK/dist"/*.tar.gz >/dev/null
wheel=$(ls "$WORK"/dist/*.whl)

step "(a) install the bare wheel into a clean venv"
"$PY" -m venv "$WORK/venv"
"$WORK/venv/bin/python" -m pip install -q "$wheel"
export PATH="$WORK/venv/bin:$PATH"
unset PYTHONPATH PROJ_LIB PROJ_DATA QT_API
# only the wheels' own PROJ data, as on a machine without proj-data: Debian's /usr/share/proj
# (its geoid grid) out of our search path (rasterio and pyproj each use their own proj.db)
export MERIS_ORTHO_PROJ_SYSTEM_DIRS=""
cd "$WORK"
python - <<'EOF'
import importlib.util, pathlib
import napari_meris_ortho
assert "site-packages" in napari_meris_ortho.__file__, napari_meris_ortho.__file__
print("installed:", pathlib.Path(napari_meris_ortho.__file__).parent)
gui = [name for name in ("napari", "qtpy", "PyQt5", "PyQt6", "PySide6", "magicgui", "vispy")
       if importlib.util.find_spec(name) is not None]
assert not gui, f"the bare wheel brought the GUI: {gui}"
print("no napari, Qt nor magicgui in the venv")
EOF
meris-ortho --version

step "(a) meris-ortho sample fr-small"
meris-ortho sample fr-small --out "$WORK/fr-small"
product=$(ls "$WORK"/fr-small/MER_*.N1 | head -1)

step "(a) meris-ortho map: tie-point heights"
meris-ortho map "$product" -o "$WORK/tiepoints.tif" --elevation tiepoints
step "(a) meris-ortho map: GeoTIFF DEM"
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

step "(b) install the napari extra into the same venv"
python -m pip install -q "$wheel[napari]"

step "(b) napari manifest validation"
npe2 validate napari-meris-ortho

step "(b) open fr-small in a napari viewer (Xvfb)"
unset QT_QPA_PLATFORM
xvfb-run -a python - "$product" <<'EOF'
import sys
import napari
import qtpy
from napari.utils.notifications import notification_manager
from qtpy.QtWidgets import QApplication

viewer = napari.Viewer(show=True)
layers = viewer.open(sys.argv[1], plugin="napari-meris-ortho")
QApplication.processEvents()
assert layers and len(viewer.layers) == len(layers), (layers, viewer.layers)
print(f"napari {napari.__version__} on {qtpy.API_NAME}:", ", ".join(l.name for l in layers))
pyqt5 = [n.message for n in notification_manager.records if "PyQt5" in str(n.message)]
assert not pyqt5, pyqt5  # napari's deprecation notice of the PyQt5 binding
viewer.close()
EOF

step ""
echo "[pip-only] $(elapsed "$t0" "$EPOCHREALTIME") s  in all"
echo "[pip-only] step times:"
printf '  %s\n' "${times[@]}"
