#!/usr/bin/env bash
# `dtif merge --inject-false-loop` on every built-in scene (config/scenes/*.yaml) and seed, and
# one table of the merged maps against ground truth (docs/results.md's merge table): ATE of
# component 0 beside the odometry-only baseline, rotation, stem inventory metrics, and the ATE
# change one injected false loop causes, between the robots with the most loops and (a second
# merge, --false-loop-weakest) as the only loop of the weakest-linked pair.
# Usage: [DTIF_SEEDS="1 2 3"] [DTIF_SIM_ONLY=1] scripts/merge_scenes.sh [scene.yaml ...]
# Datasets are shared with eval_scenes.sh (.ws/scenes, .ws/scenes-seed<n>) and reused.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
SEEDS="${DTIF_SEEDS:-1 2 3}"
dtif_scenes "$@"
[ -x "${DTIF_BIN}" ] || dtif_build_logged

for seed in ${SEEDS}; do
  [[ "${seed}" =~ ^[0-9]+$ ]] || { echo "DTIF_SEEDS: not a seed: ${seed}" >&2; exit 2; }
  if [ "${seed}" = 1 ]; then base="${DTIF_WS}/scenes"; else base="${DTIF_WS}/scenes-seed${seed}"; fi
  for scene in "${SCENES[@]}"; do
    name="$(basename "${scene}" .yaml)"
    dir="${base}/${name}"
    dtif_scene_dataset "${scene}" "${dir}" "${seed}"
    [ "${DTIF_SIM_ONLY:-0}" = 1 ] && continue
    echo "== ${name} (seed ${seed}): merging" >&2
    "${DTIF_BIN}" merge "${dir}/dataset" --out "${dir}/merge" --inject-false-loop --quiet \
      > "${dir}/merge.log" 2>&1 || { cat "${dir}/merge.log" >&2; exit 1; }
    "${DTIF_BIN}" merge "${dir}/dataset" --out "${dir}/merge-weakest" --inject-false-loop \
      --false-loop-weakest --quiet > "${dir}/merge-weakest.log" 2>&1 ||
      { cat "${dir}/merge-weakest.log" >&2; exit 1; }
  done
done
[ "${DTIF_SIM_ONLY:-0}" = 1 ] && exit 0

/usr/bin/python3 - "${DTIF_WS}" "${SEEDS}" "${SCENES[@]}" <<'PY'
import json, os, sys
ws, seeds, scenes = sys.argv[1], sys.argv[2].split(), sys.argv[3:]


def verdict(s):
    if not s.get("false_loop_added"):
        return "NOT ADDED"
    return "used" if s.get("false_loop_used") else "rejected"


print("| Scene | seed | robots in comp. 0 | ATE [m] | odometry ATE [m] | rot [deg] | stem prec. | "
      "stem recall | duplicates | stem pos. err [m] | median DBH err [cm] | false loop | dATE [m] | "
      "weakest pair's only loop false | dATE [m] |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
for seed in seeds:
    base = os.path.join(ws, "scenes" if seed == "1" else "scenes-seed" + seed)
    for scene in scenes:
        name = os.path.basename(scene)[:-5]
        s = json.load(open(os.path.join(base, name, "merge", "summary.json")))
        sc, cl = s["score"], s.get("score_without_false_loop") or s["score"]
        c0 = cl["component"]["0"]
        inc0 = sum(1 for c in s["robot_component"].values() if c == 0)
        st = cl["stems"]
        d = s["score"]["component"]["0"]["ate_m"] - c0["ate_m"]
        w = json.load(open(os.path.join(base, name, "merge-weakest", "summary.json")))
        wd = (w["score"]["component"]["0"]["ate_m"] -
              (w.get("score_without_false_loop") or w["score"])["component"]["0"]["ate_m"])
        print(f"| {name} | {seed} | {inc0}/{s['robots']} | {c0['ate_m']:.3f} | "
              f"{cl['odometry_only_all']['ate_m']:.3f} | {c0['rot_rms_deg']:.2f} | "
              f"{st['precision']:.3f} | {st['recall']:.3f} | {100 * st['duplicate_rate']:.1f} % | "
              f"{st['mean_pos_err_m']:.3f} | {100 * st['median_dbh_err_m']:.1f} | "
              f"{verdict(s)} | {d:+.4f} | {verdict(w)} | {wd:+.4f} |")
PY
