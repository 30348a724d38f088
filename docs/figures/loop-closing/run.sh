#!/usr/bin/env bash
# Loop closing live: the default device over the LTE-like uplink, the edge without loop
# closing (the default) and with it (loops.yaml), the same seeds, one run at a time, on one of
# two walks:
#   WALK=revisit (the default): the whole revisit-v15 walk of the bundled 7-Scenes sample
#     (1000 frames forward and back), into no-loops/ and loops/; loops-20-inliers/ holds the
#     first measurement with loop closing (20a2a85: loops on 20 inliers, no correction gate),
#     made the same way into loops/ then.
#   WALK=corridor: the synthetic corridor walked out and back twice (5400 frames, 4 x 21 m,
#     played once: the walk itself returns), into corridor-no-loops/ and corridor-loops/.
#
#   bash docs/figures/loop-closing/run.sh                      # ~2 min a run on 2 cores; resumes
#   SEEDS=10 bash docs/figures/loop-closing/run.sh             # more seeds, keeping the runs made
#   WALK=corridor SEEDS=3 bash docs/figures/loop-closing/run.sh   # ~4 min a run
set -euo pipefail
cd "$(dirname "$0")/../../.."
OUT=${OUT:-docs/figures/loop-closing}
case "${WALK:-revisit}" in
  revisit) walk=(--sequence ../shared/data/7scenes-1000 --frames 1000 --scenario revisit-v15@lte)
           prefix="" ;;
  corridor) walk=(--sequence synthetic-corridor:5400 --frames 5400 --scenario forward@lte)
            prefix="corridor-" ;;
  *) echo "WALK is revisit or corridor, got ${WALK}" >&2; exit 2 ;;
esac
for variant in "no-loops config/twinslam.yaml" "loops docs/figures/loop-closing/loops.yaml"; do
  read -r name params <<< "$variant"
  .venv/bin/twinslam evaluate "${walk[@]}" --seeds "${SEEDS:-6}" --policy lff \
    --params "$params" --out "$OUT/$prefix$name" --resume
done
