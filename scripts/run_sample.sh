#!/usr/bin/env bash
# Main job on the bundled sample: install, simulate the default scene, orthorectify it, show the result.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export PATH="$PWD/.venv/bin:$PATH"
OUT=${OUT:-out}
mkdir -p "$OUT"
meris-ortho sample fr-alps --out "$OUT/fr-alps"
meris-ortho info "$OUT/fr-alps/product.N1"
