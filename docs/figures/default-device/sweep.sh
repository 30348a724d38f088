#!/usr/bin/env bash
# The sweep that picks the default device (docs/results/any-uplink.md): each device variant
# over the uplink families and scenarios, LFF (the best rule wherever the map binds), the same
# seeds for every variant, one run at a time so that no camera frame drops. revisit-v15 plays
# the whole 1000-frame walk forward and back; revisit-v25 and outages its first 300 frames.
# Each variant's folder holds runs.csv and calibration_frames.csv; docs/figures/
# device_variants.py --user prints the tables (FOLDER#SCENARIO), paired by seed against the
# first variant.
#
#   bash docs/figures/default-device/sweep.sh         # ~7.5 h on 2 cores; resumes where it
#                                                     # stopped (evaluate --resume)
#   SEEDS=3 LONG_FRAMES=300 OUT=docs/figures/default-device/pilot-300 SHORT= \
#       LONG=revisit-v15@table1,revisit-v15@lte,revisit-v15@mmwave,revisit-v15@constrained,outages@lte \
#       bash docs/figures/default-device/sweep.sh        # the pilot: 45 runs, 18 min
#   SEEDS=3 SHORT= bash docs/figures/default-device/sweep.sh      # the whole walk, 3 seeds
set -euo pipefail
cd "$(dirname "$0")/../../.."
SEEDS=${SEEDS:-10}
LONG_FRAMES=${LONG_FRAMES:-1000}
SHORT_FRAMES=${SHORT_FRAMES:-300}
LONG=${LONG-revisit-v15@table1,revisit-v15@lte,revisit-v15@mmwave,revisit-v15@constrained}
SHORT=${SHORT-revisit-v25@table1,revisit-v25@lte,revisit-v25@mmwave,revisit-v25@constrained,outages@lte,outages@constrained}
OUT=${OUT:-docs/figures/default-device}
VARIANTS=(
  # the paper's Table I device: 2 s slots, D_req 0.5 s, no restores, no own points
  "table-i docs/figures/colour-camera/table1.yaml edge"
  # the tuned paper device: 1 s slots, D_req 0.25 s, restores, its own points after 0.1 s lost
  "short-loop-own-map docs/figures/colour-camera/short-loop-own-map.yaml edge"
  # the Edge-SLAM style device with the same slots: the edge's map and its own recent points
  "edge-local docs/figures/colour-camera/short-loop-own-map.yaml edge+local"
  # the same without the edge's local bundle adjustment (docs/results/map-consistency.md)
  "no-adjustment docs/figures/map-consistency/no-adjustment.yaml edge+local"
  # and with fusion on integration and loop closing: the default device
  "loops-fusion docs/figures/map-consistency/loops.yaml edge+local"
)
run() {   # FRAMES SCENARIOS FOLDER-SUFFIX
  [ -n "$2" ] || return 0
  for variant in "${VARIANTS[@]}"; do
    read -r name params source <<< "$variant"
    .venv/bin/twinslam evaluate --sequence ../shared/data/7scenes-1000 --frames "$1" \
      --seeds "$SEEDS" --policy lff --scenario "$2" --params "$params" \
      --map-source "$source" --out "$OUT/$name-$3" --resume
  done
}
run "$LONG_FRAMES" "$LONG" "$LONG_FRAMES"
run "$SHORT_FRAMES" "$SHORT" "$SHORT_FRAMES"
