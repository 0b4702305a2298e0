#!/usr/bin/env bash
# Main job on the bundled sample: install, simulate the default scene (fr-alps, 2241 x 2241 FR),
# then orthorectify it with its DEM onto the default geographic grid (MERSYN use case 3).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export PATH="$PWD/.venv/bin:$PATH"
OUT=${OUT:-out}
SCENE=${SCENE:-fr-alps}
mkdir -p "$OUT"
meris-ortho sample "$SCENE" --out "$OUT/$SCENE"
product=$(ls "$OUT/$SCENE"/MER_*.N1 | head -1)
meris-ortho info "$product" | head -40
meris-ortho map "$product" -o "$OUT/$SCENE/ortho_dem.tif" --dem "$OUT/$SCENE/dem_truth.tif" \
    --stats-json "$OUT/$SCENE/ortho_dem.json"
echo "orthorectified product: $OUT/$SCENE/ortho_dem.tif"
