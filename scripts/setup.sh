#!/usr/bin/env bash
# Idempotent set-up on a fresh Debian machine (root, Python 3.11): system packages, venv, package.
# Usage: bash scripts/setup.sh [--gui]   (--gui adds the X server and Qt libraries for the napari tests)
set -euo pipefail
cd "$(dirname "$0")/.."
GUI=0
[[ "${1:-}" == "--gui" ]] && GUI=1

apt_pkgs=()
command -v python3 >/dev/null || apt_pkgs+=(python3 python3-venv python3-pip)
# gdal-bin: gdalwarp, the peer of benchmarks/bench_ortho.py (our own GDAL comes with rasterio), and
# gdalbuildvrt (a VRT of Copernicus DEM tiles is one DEM entry; tests build one)
command -v gdalwarp >/dev/null || apt_pkgs+=(gdal-bin)
# proj-data: the EGM96 geoid grid (/usr/share/proj/egm96_15.gtx) for DEM heights above the geoid
[[ -f /usr/share/proj/egm96_15.gtx ]] || apt_pkgs+=(proj-data)
if [[ $GUI == 1 ]]; then
    for p in xvfb xauth libxcb-icccm4 libxcb-keysyms1 libgl1 libegl1 libxkbcommon-x11-0 libxcb-cursor0 \
             libdbus-1-3 libxcb-image0 libxcb-render-util0 libxcb-xinerama0 libxcb-randr0 libxcb-shape0 \
             libfontconfig1; do
        dpkg -s "$p" >/dev/null 2>&1 || apt_pkgs+=("$p")
    done
fi
if (( ${#apt_pkgs[@]} )); then
    SUDO=""; [[ $(id -u) != 0 ]] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${apt_pkgs[@]}" >/dev/null
fi

PY=${PYTHON:-python3}
if [[ ! -x .venv/bin/python ]]; then
    "$PY" -m venv .venv
fi
stamp=.venv/.installed-$(sha1sum pyproject.toml | cut -c1-12)
if [[ ! -f $stamp ]]; then
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -e ".[test]"
    # the viewer runs on PyQt6 (the `napari` extra); a PyQt5 left in the venv by an older
    # install would be qtpy's first choice, and napari deprecates it
    if .venv/bin/python -m pip show -q PyQt5 >/dev/null 2>&1; then
        .venv/bin/python -m pip uninstall -q -y PyQt5 PyQt5-Qt5 PyQt5-sip
    fi
    rm -f .venv/.installed-*
    touch "$stamp"
    # compile the numba kernels of `meris-ortho map` in the background (a user's first map then
    # loads them from the cache); the test runner compiles them itself
    if [[ -z "${MERIS_ORTHO_NO_WARMUP:-}" ]]; then
        nohup .venv/bin/python -m napari_meris_ortho.warmup >/dev/null 2>&1 &
    fi
fi
# bytecode of our own (editable) sources, as pip writes it for installed packages: a run then
# does not compile 75 modules first (0.08 s of every `meris-ortho` call), also where
# PYTHONDONTWRITEBYTECODE keeps Python from caching it; only changed sources are compiled
.venv/bin/python -m compileall -q src >/dev/null
