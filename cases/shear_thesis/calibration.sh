#!/usr/bin/env bash
# The calibration charts of the reference thesis's chapter 4 with cfddem (docs/shear-cell.md,
# "Calibration with the thesis's material"): bulk friction against particle friction (spheres,
# rolling friction 0-0.5, rotation locked, the thesis's 2-sphere clump and a 4-sphere clump) and
# wall friction against particle-plate friction (the plate variant, free and locked rotation),
# two fills per point.  Each `cfddem calibrate` call adds to its study folder and reuses the
# finished runs in it, so the script can be stopped and started again.
#
#   bash cases/shear_thesis/calibration.sh [OUT] [reduced|full]
#
# reduced (default): a 60 mm cell (1,900 spheres filled, about 1,200 after scraping; one point
# costs about a minute on one core); full: the thesis's 95 mm cell (4,700 spheres; 2-3 minutes).
set -euo pipefail
OUT=${1:-runs/shear_thesis_calibration}
SIZE=${2:-reduced}
CASE=$(dirname "$0")
if [ "$SIZE" = reduced ]; then
  CELL=(--set shear.cell_diameter=0.06); NS=1900; NW=950; NC2=2800; NC4=700
elif [ "$SIZE" = full ]; then
  CELL=(); NS=4700; NW=2350; NC2=7000; NC4=1750
else
  echo "size must be 'reduced' or 'full', got '$SIZE'" >&2; exit 2
fi
MU=0.1,0.35,0.6,1.0
CLUMP2=(--set 'particles.clump="template"' --set 'particles.clump_spheres=[[-0.125,0,0,0.5],[0.125,0,0,0.5]]'
        --set particles.diameter=0.003 --set time.dt=2.6e-6)
run() { cfddem calibrate "$CASE" --threads 1 "${CELL[@]}" "$@"; }
# 1. spheres, free rotation, mu_r 0 and 0.1, then rotation locked
run --mu $MU --mu-r 0,0.1 --replicas 2 --set shear.n_particles=$NS --out "$OUT/bulk"
run --mu $MU --mu-r 0 --rotation locked --replicas 2 --set shear.n_particles=$NS --out "$OUT/bulk"
# 2. wall friction on the plate, free and locked
run --mu-wall 0.1,0.17,0.3,0.5,0.75,1.0 --mu-r 0 --rotation free,locked --replicas 2 \
    --set shear.n_particles=$NW --out "$OUT/wall"
# 3. the thesis's 2-sphere clump (3 mm spheres 0.75 mm apart), mu_r 0 and 0.1
run --mu $MU --mu-r 0,0.1 --label clump2 "${CLUMP2[@]}" --set shear.n_particles=$NC2 --out "$OUT/bulk"
# 4. spheres: the rest of the rolling friction range
run --mu $MU --mu-r 0.05,0.2,0.5 --replicas 2 --set shear.n_particles=$NS --out "$OUT/bulk"
# 5. a 4-sphere clump (tetrahedron of 3.8 mm spheres, edge d/2)
run --mu $MU --mu-r 0 --label clump4 --set 'particles.clump="pellet4"' --set shear.n_particles=$NC4 --out "$OUT/bulk"
# 6. second fills of the clumps
run --mu $MU --mu-r 0,0.1 --replicas 2 --label clump2 "${CLUMP2[@]}" --set shear.n_particles=$NC2 --out "$OUT/bulk"
run --mu $MU --mu-r 0 --replicas 2 --label clump4 --set 'particles.clump="pellet4"' --set shear.n_particles=$NC4 --out "$OUT/bulk"
# 7. every point of a row from the same dense packing: filled at mu = 0.15 (the thesis's silo
#    fill), the case's friction from the scraping on; the mu_r = 0.5 row also filled at mu_r = 0
#    (filled at its own mu_r it stays loose and jams: docs/shear-cell.md)
run --mu $MU --mu-r 0,0.1 --replicas 2 --label spheres_fill015 --set shear.fill_friction=0.15 \
    --set shear.n_particles=$NS --out "$OUT/bulk"
run --mu $MU --mu-r 0 --rotation locked --replicas 2 --label spheres_fill015 --set shear.fill_friction=0.15 \
    --set shear.n_particles=$NS --out "$OUT/bulk"
run --mu $MU --mu-r 0.5 --replicas 2 --label spheres_fill015_r0 --set shear.fill_friction=0.15 \
    --set shear.fill_rolling_friction=0 --set shear.n_particles=$NS --out "$OUT/bulk"
