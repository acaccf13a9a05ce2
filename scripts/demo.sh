#!/usr/bin/env bash
# README command 1: sets everything up on a fresh Debian 12 machine, simulates a forest survey
# by several robots (built-in scene) as a dataset and as a rosbag, then
#  1. runs the offline evaluation protocol (dtif eval) on the dataset and prints its table;
#  2. replays the bag through the ROS nodelets (roslaunch dtif demo_bag.launch, headless, all
#     nodelets in one manager) and prints the loop closures they found against the dataset's
#     ground truth (dtif score: eval's metrics), side by side with eval's, and their lag;
#  3. prints the merged map of dtif merge (offline) and of the map merge nodelet (its save_map,
#     scored by scripts/score_ros_merge.py: ATE per map frame and per robot, odometry beside).
# Exits non-zero when a step fails or when the nodelets or dtif eval close no loop.
# Usage: scripts/demo.sh [scene.yaml] (default: config/scenes/mixed.yaml)
# Environment: DTIF_DEMO_RATE (bag replay rate, default 2), DTIF_DEMO_SEED (simulation seed,
# default 1: another seed is another forest and routes, in demo/<scene>-seed<n>), DTIF_DEMO_BAG_ARGS (more options of
# dtif simulate, e.g. "--bag-max-points 4000" for a smaller bag of thinned clouds; by default the
# bag holds every return, so the nodelets assemble the dataset's submaps; "--bag-layout fastlio", or
# a scene with bag_layout: fastlio, gives a bag per robot with stock FAST-LIO2 names, each played
# remapped into its robot's namespace as README "Your own FAST-LIO2 units and bags" tells),
# DTIF_DEMO_SUBMAP_CLOUD (1, the default: the extraction nodelets publish their submap clouds, so
# the map merge nodelet measures the inventory's DBH on their points as dtif merge does, and
# saves a merged cloud; 0: they do not, and the nodelet keeps the observations' median DBH),
# DTIF_DEMO_FALSE_LOOP (1: scripts/inject_false_loop.py publishes one false loop on /loop_closures
# once half as many loops as dtif eval's have come, as dtif merge --inject-false-loop does offline;
# the map's score then says whether the back end used it).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
SCENE="${1:-${DTIF_REPO}/config/scenes/mixed.yaml}"
RATE="${DTIF_DEMO_RATE:-2}"
START_S="$(date +%s)"
SEED="${DTIF_DEMO_SEED:-1}"
NAME="$(basename "${SCENE}" .yaml)"
OUT="${DTIF_WS}/demo/${NAME}"
[ "${SEED}" = 1 ] || OUT="${OUT}-seed${SEED}"

dtif_build_logged
dtif_source_ws
# The simulation is reused when this scene was already simulated by the same dtif binary with
# the same bag options (a few minutes saved on a re-run); otherwise it is made anew.
SIM_KEY="seed ${SEED} ${DTIF_DEMO_BAG_ARGS:-}"
if [ -f "${OUT}/simulated" ] && [ "$(cat "${OUT}/simulated")" = "${SIM_KEY}" ] \
    && [ "${OUT}/simulated" -nt "${SCENE}" ] && [ "${OUT}/simulated" -nt "${DTIF_BIN}" ]; then
  echo "dtif demo: reusing the simulation of ${SCENE} in ${OUT}"
else
  echo "dtif demo: simulating ${SCENE} -> ${OUT}/dataset and ${OUT}/${NAME}.bag"
  rm -rf "${OUT}"
  # shellcheck disable=SC2086  # DTIF_DEMO_BAG_ARGS holds options
  "${DTIF_BIN}" simulate "${SCENE}" --out "${OUT}/dataset" --seed "${SEED}" --png "${OUT}/scene.png" \
    --bag "${OUT}/${NAME}.bag" ${DTIF_DEMO_BAG_ARGS:-}
  echo "${SIM_KEY}" > "${OUT}/simulated"
fi
# The bags to play: one (/<robot>/... topics), or one per robot (fastlio layout, stock names).
dtif_robots "${OUT}/dataset"
if [ -f "${OUT}/${NAME}.bag" ]; then
  BAGS=("${OUT}/${NAME}.bag")
else
  BAGS=()
  for r in "${ROBOTS[@]}"; do BAGS+=("${OUT}/${NAME}_${r}.bag"); done
fi
echo "dtif demo: $(du -cb "${BAGS[@]}" | tail -1 | awk '{printf "%d", $1 / 1e6}') MB of bags:" \
  "$(basename -a "${BAGS[@]}" | tr '\n' ' ')"
rm -rf "${OUT}/eval" "${OUT}/merge" "${OUT}/ros"

echo "dtif demo: 1. dtif eval on the dataset (results in ${OUT}/eval)"
"${DTIF_BIN}" eval "${OUT}/dataset" --out "${OUT}/eval" --quiet
echo "dtif demo: 1b. dtif merge on the dataset (results in ${OUT}/merge)"
"${DTIF_BIN}" merge "${OUT}/dataset" --out "${OUT}/merge" --quiet > "${OUT}/merge.txt"

# 2. The ROS nodelets on the bag: a private master (other roscores on this machine are left
# alone); the script plays the bag itself so that the last submaps can finish before shutdown.
dtif_private_master
LOG="${OUT}/ros/loops.csv"
mkdir -p "${OUT}/ros"
echo "dtif demo: 2. roslaunch dtif demo_bag.launch (robots ${ROBOTS[*]}), rosbag play at rate" \
  "${RATE} (logs in ${OUT}/ros)"
roslaunch -p "${DTIF_PORT}" dtif demo_bag.launch play:=false headless:=true bond:=false \
  robot1:="${ROBOTS[0]}" robot2:="${ROBOTS[1]:-}" robot3:="${ROBOTS[2]:-}" \
  publish_submap_cloud:="$([ "${DTIF_DEMO_SUBMAP_CLOUD:-1}" = 0 ] && echo false || echo true)" \
  loop_log:="${LOG}" > "${OUT}/ros/roslaunch.log" 2>&1 &
LAUNCH_PID=$!
trap 'kill -INT ${LAUNCH_PID} ${INJECT_PID:-} 2>/dev/null || true' EXIT
# Ready when the loop log is open and the last robot's extraction nodelet subscribes its clouds.
subscribed() {
  rostopic info "/${ROBOTS[-1]}/cloud_registered" 2>/dev/null | sed -n '/Subscribers:/,$p' \
    | grep -q '\*'
}
for _ in $(seq 1 120); do
  if [ -s "${LOG}" ] && subscribed; then break; fi
  kill -0 "${LAUNCH_PID}" 2>/dev/null || break
  sleep 0.5
done
if ! { [ -s "${LOG}" ] && subscribed; }; then
  cat "${OUT}/ros/roslaunch.log"
  echo "dtif demo: the nodelets did not start" >&2
  exit 1
fi
# --delay: the player waits after advertising, so that every subscriber is connected before the
# first message (the default 0.2 s lost alpha's first clouds on a loaded machine, and each robot's
# submap windows start at its first cloud received).
DELAY_S=2
INJECT_PID=""
if [ "${DTIF_DEMO_FALSE_LOOP:-0}" = 1 ]; then
  HALF="$(/usr/bin/python3 -c 'import json, sys; print(max(1, json.load(open(sys.argv[1]))["accepted"] // 2))' \
    "${OUT}/eval/summary.json")"
  echo "dtif demo: a false loop goes to /loop_closures once ${HALF} loops, one of them between" \
    "two robots, have come (${OUT}/ros/false_loop.csv)"
  /usr/bin/python3 "${DTIF_REPO}/scripts/inject_false_loop.py" --robots "${ROBOTS[@]}" \
    --after "${HALF}" --out "${OUT}/ros/false_loop.csv" > "${OUT}/ros/false_loop.log" 2>&1 &
  INJECT_PID=$!
fi
t0=$(date +%s.%N)
if [ ${#BAGS[@]} -eq 1 ]; then
  rosbag play --clock --quiet --delay "${DELAY_S}" --rate "${RATE}" "${BAGS[0]}"
else
  # A player per unit, its stock topics into the unit's namespace (its own /tf out of the way);
  # the longest bag's player publishes the clock (the simulated units share a time base and
  # start together, as synchronised units would).
  CLOCK_I=0
  for i in "${!BAGS[@]}"; do
    if awk -v a="$(rosbag info -y -k duration "${BAGS[i]}")" \
        -v b="$(rosbag info -y -k duration "${BAGS[CLOCK_I]}")" 'BEGIN { exit !(a > b) }'; then
      CLOCK_I=${i}
    fi
  done
  PLAYERS=()
  for i in "${!ROBOTS[@]}"; do
    r="${ROBOTS[i]}"
    rosbag play $([ "${i}" -eq "${CLOCK_I}" ] && echo --clock) --quiet --delay "${DELAY_S}" --rate "${RATE}" \
      "${BAGS[i]}" /cloud_registered:=/"${r}"/cloud_registered /Odometry:=/"${r}"/Odometry \
      /tf:=/"${r}"/fastlio_tf &
    PLAYERS+=($!)
  done
  wait "${PLAYERS[@]}"
fi
t1=$(date +%s.%N)
# The last submaps are still being processed: wait until the log has been quiet for 5 s.
for _ in $(seq 1 60); do
  [ $(( $(date +%s) - $(stat -c %Y "${LOG}") )) -ge 5 ] && break
  sleep 1
done
# The map merge nodelet's map (TF map -> odometry frames comes from the same solve).
[ -z "${INJECT_PID}" ] || kill -INT "${INJECT_PID}" 2>/dev/null || true
rosservice call /map_merge/get_map_info > "${OUT}/ros/map_info.yaml" 2>&1 || true
rosservice call /map_merge/save_map "directory: '${OUT}/ros/map'" > "${OUT}/ros/save_map.log" 2>&1 \
  || true
kill -INT "${LAUNCH_PID}" 2>/dev/null || true
wait "${LAUNCH_PID}" 2>/dev/null || true
trap - EXIT
BAG_S="$(rosbag info -y -k duration "${BAGS[${CLOCK_I:-0}]}")"
awk -v b="${BAG_S}" -v t0="${t0}" -v t1="${t1}" -v r="${RATE}" -v d="${DELAY_S}" 'BEGIN {
  printf "dtif demo: played %.1f s of bag in %.1f s of wall time (rate %s)\n", b, t1 - t0 - d, r }'
grep -E "WARN|ERROR|FATAL" "${OUT}/ros/roslaunch.log" | head -5 || true

echo
echo "=== dtif eval on ${NAME} (offline, ${OUT}/eval/table.md) ==="
cat "${OUT}/eval/table.md"
echo
echo "=== ROS nodelets on ${NAME}.bag, scored against ground truth (dtif score) ==="
"${DTIF_BIN}" score "${OUT}/dataset" --loops "${LOG}" --out "${OUT}/ros/score" --eval "${OUT}/eval"
echo
echo "=== Merged map of ${NAME}: dtif merge (offline, ${OUT}/merge) ==="
cat "${OUT}/merge.txt"
echo
echo "=== Merged map of ${NAME}: map merge nodelet on the bag (save_map: ${OUT}/ros/map) ==="
if [ -f "${OUT}/ros/map/merged_poses.csv" ]; then
  FALSE_LOOP_ARGS=()
  if [ -n "${INJECT_PID}" ]; then
    if [ -f "${OUT}/ros/false_loop.csv" ]; then
      FALSE_LOOP_ARGS=(--false-loop "${OUT}/ros/false_loop.csv")
      sed -n 's/^.*\]: \(false loop after\)/dtif demo: \1/p' "${OUT}/ros/false_loop.log"
    else
      echo "dtif demo: no false loop was injected (fewer loops than it waited for;" \
        "${OUT}/ros/false_loop.log)" >&2
    fi
  fi
  /usr/bin/python3 "${DTIF_REPO}/scripts/score_ros_merge.py" "${OUT}/dataset" "${OUT}/ros/map" \
    "${FALSE_LOOP_ARGS[@]}"
  grep -E "loops_used|loops_rejected|solves|last_solve_ms|max_solve_ms|slice_submaps|slice_bytes" "${OUT}/ros/map_info.yaml" \
    | tr '\n' ' '
  echo
  grep -ao "save_map: DBH from the points.*" "${OUT}/ros/roslaunch.log" | tail -1 | sed 's/\x1b\[0m$//' || true
else
  echo "dtif demo: the map merge nodelet saved no map ($(cat "${OUT}/ros/save_map.log"))" >&2
  exit 1
fi
echo
# A demo that closes no loop is a failed demo (.ci/run runs it): exit non-zero.
accepted() { /usr/bin/python3 -c 'import json, sys; print(json.load(open(sys.argv[1]))["accepted"])' "$1"; }
ONLINE_LOOPS="$(accepted "${OUT}/ros/score/summary.json")"
EVAL_LOOPS="$(accepted "${OUT}/eval/summary.json")"
echo "dtif demo: loops: nodelets ${ONLINE_LOOPS}, dtif eval ${EVAL_LOOPS}"
if [ "${ONLINE_LOOPS}" -eq 0 ] || [ "${EVAL_LOOPS}" -eq 0 ]; then
  echo "dtif demo: FAILED: no loop closure (nodelets ${ONLINE_LOOPS}, dtif eval ${EVAL_LOOPS})" >&2
  exit 1
fi
echo "dtif demo: done in $(( $(date +%s) - START_S )) s of wall time"
