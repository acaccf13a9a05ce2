#!/usr/bin/env bash
# Issue #5: dtif against the paper's baselines on every built-in scene, in one run.
# Usage: scripts/bench.sh [out_dir] [scene.yaml ...]   (default out: bench/<date>)
# Reuses the datasets of scripts/eval_scenes.sh (.ws/scenes/<name>/dataset), simulating the
# missing or outdated ones as it does; runs `dtif bench` (front ends, back ends,
# precision-recall, scaling), measures
# the peak RSS of `dtif eval` on the largest scene, and draws the plots (python3-matplotlib,
# installed through scripts/install_deps.sh). Writes tables.md, *.csv and *.png into out_dir.
# About 20 min on 2 shared cores when the datasets exist.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
OUT="${1:-${DTIF_REPO}/bench/$(date +%Y-%m-%d)}"
shift || true
dtif_scenes "$@"

dtif_build_logged
bash "${DTIF_REPO}/scripts/install_deps.sh" python3-matplotlib  # the plots (Debian's, never pip)
mkdir -p "${OUT}"
DATASETS=()
for scene in "${SCENES[@]}"; do
  name="$(basename "${scene}" .yaml)"
  dtif_scene_dataset "${scene}" "${DTIF_WS}/scenes/${name}"
  DATASETS+=("${DTIF_WS}/scenes/${name}/dataset")
done

"${DTIF_BIN}" bench "${DATASETS[@]}" --out "${OUT}" > "${OUT}/bench.log"

# Peak RSS of `dtif eval` on the largest scene (most points on disk).
largest="$(du -s "${DATASETS[@]}" | sort -n | tail -1 | cut -f2)"
/usr/bin/time -v "${DTIF_BIN}" eval "${largest}" --out "${OUT}/eval_largest" --quiet \
  > /dev/null 2> "${OUT}/eval_largest.time"
rss_kb="$(sed -n 's/.*Maximum resident set size (kbytes): //p' "${OUT}/eval_largest.time")"
echo "peak RSS of dtif eval on ${largest}: $((rss_kb / 1024)) MB" | tee "${OUT}/peak_rss.txt"

/usr/bin/python3 "${DTIF_REPO}/scripts/bench_plots.py" "${OUT}"
cat "${OUT}/tables.md" "${OUT}/peak_rss.txt"
echo "(bench output: ${OUT})"
