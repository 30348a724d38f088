#!/usr/bin/env bash
# Point fusion live: the default device on the whole revisit-v15 walk over the LTE-like
# uplink, seeds 0-2, with the edge's fusion of restored keyframes' points (the default) and
# without it (no-fusion.yaml), one run at a time; the same seeds as the default-device sweep's
# edge-local-1000 folder, run before the fusion, the progress rule's priority and REP 105.
#
#   bash docs/figures/point-fusion/run.sh           # ~12 min on 2 cores; resumes
set -euo pipefail
cd "$(dirname "$0")/../../.."
OUT=${OUT:-docs/figures/point-fusion}
for variant in "fusion config/twinslam.yaml" "no-fusion docs/figures/point-fusion/no-fusion.yaml"; do
  read -r name params <<< "$variant"
  .venv/bin/twinslam evaluate --sequence ../shared/data/7scenes-1000 --frames 1000 \
    --seeds "${SEEDS:-3}" --policy lff --scenario revisit-v15@lte --params "$params" \
    --out "$OUT/$name" --resume
done
