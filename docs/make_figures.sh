#!/usr/bin/env bash
# Re-creates the figures under docs/ (each body preset in a generated outfit, walking).
set -euo pipefail
cd "$(dirname "$0")/.."
DRAPE=${DRAPE:-.venv/bin/drape}
tmp=$(mktemp -d)
$DRAPE outfits generate --type tshirt,trousers --vertices 8000 --seed 11 --body neutral --looseness 0.4 --length 0.8 --out "$tmp/neutral.obj"
$DRAPE outfits generate --type dress --vertices 8000 --seed 12 --body female --looseness 0.5 --length 0.4 --out "$tmp/female.obj"
$DRAPE outfits generate --type longsleeve,trousers,jacket --vertices 12000 --seed 13 --body male --looseness 0.0 --length 0.5 --out "$tmp/male.obj"
for body in neutral female male; do
  $DRAPE render --body "$body" --outfit "$tmp/$body.obj" --clip walk --frames 0,10,20,30 --azimuth 35 \
    --out "docs/render_${body}_walk.png"
done
$DRAPE render --body neutral --frames 0 --azimuth 0 --out docs/render_neutral_rest.png
# a real garment made for no body of ours (../shared/data/external), fitted onto the neutral body
$DRAPE outfits fit ../shared/data/external/ncsim_arcsim_tshirtw.obj --body neutral --out "$tmp/fitted.obj"
$DRAPE render --body neutral --outfit "$tmp/fitted.obj" --frames 0 --out docs/fit_arcsim_tshirt.png
rm -rf "$tmp"

# a simulated sequence of the small dataset (builds it first if needed: make sim-dataset, ~13 min)
make sim-dataset
$DRAPE render --sim data/sim/skirt/items/skirt__p02__walk.npz --frames 0,15,30,45,60,75,89 \
  --out docs/sim_skirt_walk.png
# the intrinsic skirt keyframed on a held-out simulation (needs make intrinsic-data's test items)
$DRAPE render --sim data/intrinsic/skirt/items/skirt__p40__walk.npz --keyframes 24,119 --frames 24,48,72,96,119 \
  --out docs/intrinsic_skirt_walk.png
# the same for the long skirt (needs make intrinsic-data-long-skirt's test items)
$DRAPE render --sim data/intrinsic/long_skirt/items/long_skirt__p40__walk.npz --keyframes 24,119 \
  --frames 24,48,72,96,119 --out docs/intrinsic_long_skirt_walk.png
# drape's layers (MGN's inner and outer networks) beside a two-layer simulation of a held-out H_in and motion
# (a validation sequence of make layers-data)
$DRAPE render --sim "data/layers/tshirt_jacket/items/tshirt+jacket__p06__proc7.npz" --served --frames 0,20,40,60,89 \
  --out docs/layers_tshirt_jacket_served.png
