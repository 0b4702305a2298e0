#!/usr/bin/env bash
# Whole test suite: install (with Xvfb for the napari tests), lint (ruff, mypy), then pytest
# under Xvfb.
set -euo pipefail
cd "$(dirname "$0")/.."
MERIS_ORTHO_NO_WARMUP=1 bash scripts/setup.sh --gui
export PATH="$PWD/.venv/bin:$PATH"
unset QT_QPA_PLATFORM
ruff check src tests benchmarks
mypy  # configuration and files in pyproject.toml [tool.mypy]
python -m pytest "$@"
