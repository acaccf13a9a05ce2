#!/usr/bin/env bash
# Issue #18's speed benchmark, before and after in one run: builds the speed probe against the
# commit before the speed work (scripts/build_before.sh) and runs `dtif bench --speed-only` with
# it on seeds 1-3 of every built-in scene (simulated when missing, as scripts/eval_scenes.sh
# does): descriptor time per submap, the protocol's query time per dataset, query time, memory
# and load time at 1,000 / 5,000 / 10,000 / 20,000 entries. Writes speed.md, speed_*.csv and
# the plots speed_vs_database.png and speed_vs_points.png into out_dir.
# Usage: scripts/bench_speed.sh [out_dir] [before_commit]
#   (default out: bench/speed-<date>; default before: 7bc3e70). Run it on a quiet machine:
#   ~40 min on 2 cores when the datasets exist (each measurement runs twice, before and after).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
OUT="${1:-${DTIF_REPO}/bench/speed-$(date +%Y-%m-%d)}"
BEFORE="${2:-7bc3e70}"
dtif_scenes

dtif_build_logged
bash "${DTIF_REPO}/scripts/install_deps.sh" python3-matplotlib
echo "== building the speed probe against ${BEFORE}" >&2
PROBE="$(bash "${DTIF_REPO}/scripts/build_before.sh" "${BEFORE}")"
DATASETS=()
for seed in 1 2 3; do
  if [ "${seed}" = 1 ]; then base="${DTIF_WS}/scenes"; else base="${DTIF_WS}/scenes-seed${seed}"; fi
  for scene in "${SCENES[@]}"; do
    name="$(basename "${scene}" .yaml)"
    dtif_scene_dataset "${scene}" "${base}/${name}" "${seed}"
    DATASETS+=("${base}/${name}/dataset")
  done
done
mkdir -p "${OUT}"
"${DTIF_BIN}" bench "${DATASETS[@]}" --out "${OUT}" --speed-only --before-probe "${PROBE}" \
  --speed-every "${DTIF_SPEED_EVERY:-2}" > "${OUT}/speed.log"
/usr/bin/python3 "${DTIF_REPO}/scripts/bench_plots.py" "${OUT}"
cat "${OUT}/speed.md"
echo "(speed benchmark: ${OUT})"
