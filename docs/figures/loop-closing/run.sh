#!/usr/bin/env bash
# Loop closing live: the default device on the whole revisit-v15 walk (1000 frames forward
# and back) over the LTE-like uplink, the edge without loop closing (the default) and with it
# (loops.yaml), the same seeds, one run at a time. loops-20-inliers/ holds the first
# measurement with loop closing (20a2a85: loops on 20 inliers, no correction gate), made the
# same way into loops/ then.
#
#   bash docs/figures/loop-closing/run.sh            # ~2 min a run on 2 cores; resumes
#   SEEDS=10 bash docs/figures/loop-closing/run.sh   # more seeds, keeping the runs made
set -euo pipefail
cd "$(dirname "$0")/../../.."
OUT=${OUT:-docs/figures/loop-closing}
for variant in "no-loops config/twinslam.yaml" "loops docs/figures/loop-closing/loops.yaml"; do
  read -r name params <<< "$variant"
  .venv/bin/twinslam evaluate --sequence ../shared/data/7scenes-1000 --frames 1000 \
    --seeds "${SEEDS:-6}" --policy lff --scenario revisit-v15@lte --params "$params" \
    --out "$OUT/$name" --resume
done
