#!/usr/bin/env bash
# Soak test of the ROS nodelets (issue #17; a script, not in CI: ~40 min to simulate once, then
# ~15 min per run). Six units replayed at 5x for an hour of bag time:
#  1. simulates config/soak/soak.yaml (6 robots, an hour each, on one plot; ~6 GB bag, reused
#     by later runs);
#  2. roslaunch dtif soak.launch: a nodelet manager per unit (trunk extraction) and the base
#     station's (loop closure + map merge), on a private master; scripts/soak_monitor.py records
#     every descriptor and loop published and samples each process's memory (VmRSS), open file
#     descriptors and threads every DTIF_SOAK_PERIOD_S of wall time; rosbag play at the rate;
#  3. after the last submap: database size, map-merge info and the database file (bytes per
#     entry); scripts/soak_reload.sh: that file loaded by a fresh base station (the memory the
#     database takes without the run's history); then dtif eval on the dataset (the offline reference for the loops, once) and
#     dtif score on the loop log (loops against ground truth and against eval's);
#  4. scripts/soak_report.py: accounting, memory and lag verdicts, plots (rss.png, lag.png),
#     summary.md; exits non-zero when memory does not level off, the lag reaches the limit or
#     anything published is unaccounted for (criteria: docs/ros.md "Soak test").
# Usage: scripts/soak.sh [scene.yaml] (default: config/soak/soak.yaml); results in
# .ws/soak/<scene>/run (the plots of the docs: cp .ws/soak/soak/run/{rss,lag}.png docs/soak_*).
# Environment: DTIF_SOAK_RATE (default 5), DTIF_SOAK_BAG_S (play only the first N s of bag time,
# e.g. 300 for a quick check; default: all), DTIF_SOAK_PERIOD_S (default 5),
# DTIF_SOAK_MAX_LAG_S (default 1.0, wall time), DTIF_SOAK_CALL_S (longest service call, 60).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
SCENE="${1:-${DTIF_REPO}/config/soak/soak.yaml}"
RATE="${DTIF_SOAK_RATE:-5}"
PERIOD_S="${DTIF_SOAK_PERIOD_S:-5}"
START_S="$(date +%s)"
NAME="$(basename "${SCENE}" .yaml)"
OUT="${DTIF_WS}/soak/${NAME}"
BAG="${OUT}/${NAME}.bag"
RUN="${OUT}/run"

dtif_build_logged
bash "${DTIF_REPO}/scripts/install_deps.sh" python3-matplotlib  # the plots (Debian's, never pip)
dtif_source_ws
# The simulation (the longest step) is reused while the scene file is unchanged.
if [ -f "${OUT}/simulated" ] && [ "${OUT}/simulated" -nt "${SCENE}" ] && [ -f "${BAG}" ]; then
  echo "dtif soak: reusing the simulation of ${SCENE} in ${OUT}"
else
  echo "dtif soak: simulating ${SCENE} -> ${OUT}/dataset and ${BAG} (long)"
  rm -rf "${OUT}"
  mkdir -p "${OUT}"
  "${DTIF_BIN}" simulate "${SCENE}" --out "${OUT}/dataset" --seed 1 --png "${OUT}/scene.png" \
    --bag "${BAG}" | tee "${OUT}/simulate.log"
  echo "seed 1" > "${OUT}/simulated"
fi
dtif_robots "${OUT}/dataset"
if [ ${#ROBOTS[@]} -ne 6 ]; then
  echo "dtif soak: ${SCENE} has ${#ROBOTS[@]} robots; launch/soak.launch runs six" >&2
  exit 1
fi
BAG_START="$(rosbag info -y -k start "${BAG}")"
BAG_S="$(rosbag info -y -k duration "${BAG}")"
PLAY_S="${DTIF_SOAK_BAG_S:-${BAG_S}}"
echo "dtif soak: $(du -b "${BAG}" | awk '{printf "%d", $1 / 1e6}') MB bag, ${BAG_S} s;" \
  "playing ${PLAY_S} s of it at rate ${RATE}"

rm -rf "${RUN}"
mkdir -p "${RUN}"
dtif_private_master
LOG="${RUN}/loops.csv"
roslaunch -p "${DTIF_PORT}" dtif soak.launch robot1:="${ROBOTS[0]}" robot2:="${ROBOTS[1]}" \
  robot3:="${ROBOTS[2]}" robot4:="${ROBOTS[3]}" robot5:="${ROBOTS[4]}" robot6:="${ROBOTS[5]}" \
  loop_log:="${LOG}" > "${RUN}/roslaunch.log" 2>&1 &
LAUNCH_PID=$!
MONITOR_PID=""
cleanup() {
  [ -n "${MONITOR_PID}" ] && kill -INT "${MONITOR_PID}" 2>/dev/null
  kill -INT "${LAUNCH_PID}" 2>/dev/null || true
}
trap cleanup EXIT
# Ready when the loop log is open and every unit's extraction nodelet subscribes its clouds.
subscribed() {
  rostopic info "/$1/cloud_registered" 2>/dev/null | sed -n '/Subscribers:/,$p' | grep -q '\*'
}
ready() {
  [ -s "${LOG}" ] || return 1
  for r in "${ROBOTS[@]}"; do subscribed "${r}" || return 1; done
}
for _ in $(seq 1 240); do
  ready && break
  kill -0 "${LAUNCH_PID}" 2>/dev/null || break
  sleep 0.5
done
if ! ready; then
  cat "${RUN}/roslaunch.log"
  echo "dtif soak: the nodelets did not start" >&2
  exit 1
fi
ROBOT_LIST="$(IFS=,; echo "${ROBOTS[*]}")"
/usr/bin/python3 "${DTIF_REPO}/scripts/soak_monitor.py" --out "${RUN}" --robots "${ROBOT_LIST}" \
  --root $$ --period "${PERIOD_S}" __name:=soak_monitor > "${RUN}/monitor.log" 2>&1 &
MONITOR_PID=$!
sleep 3  # the monitor's subscriptions connect before the first message
echo "dtif soak: nodelets up; rosbag play (started $(date -u +%H:%M:%S) UTC, ~$(awk \
  -v b="${PLAY_S}" -v r="${RATE}" 'BEGIN { printf "%d", b / r / 60 + 1 }') min)"
DELAY_S=2
t0=$(date +%s.%N)
rosbag play --clock --quiet --delay "${DELAY_S}" --rate "${RATE}" -u "${PLAY_S}" "${BAG}"
t1=$(date +%s.%N)
# The last submaps are still being processed: wait until the loop log has been quiet for 10 s.
for _ in $(seq 1 120); do
  [ $(( $(date +%s) - $(stat -c %Y "${LOG}") )) -ge 10 ] && break
  sleep 1
done
# Each call bounded (rosservice ignores SIGTERM: -k): a service whose nodelet holds its lock in
# a long computation (the map merge's re-solve) must not hang the test.
call() { timeout -k 2 "${DTIF_SOAK_CALL_S:-60}" rosservice call "$@"; }
call /loop_closure/database_size > "${RUN}/database_size.yaml" 2>&1 || true
call /map_merge/get_map_info > "${RUN}/map_info.yaml" 2>&1 || true
call /loop_closure/save_database "path: '${RUN}/database.bin'" > "${RUN}/save_database.yaml" 2>&1 \
  || true
sleep "${PERIOD_S}"  # one more sample of every process after the run
kill -INT "${MONITOR_PID}" 2>/dev/null || true
wait "${MONITOR_PID}" 2>/dev/null || true
MONITOR_PID=""
kill -INT "${LAUNCH_PID}" 2>/dev/null || true
wait "${LAUNCH_PID}" 2>/dev/null || true
trap - EXIT
awk -v b="${PLAY_S}" -v t0="${t0}" -v t1="${t1}" -v r="${RATE}" -v d="${DELAY_S}" 'BEGIN {
  printf "dtif soak: played %.0f s of bag in %.0f s of wall time (rate %s)\n", b, t1 - t0 - d, r
}' | tee "${RUN}/played.txt"
# The saved database in a fresh base station: its memory without the run's history.
bash "${DTIF_REPO}/scripts/soak_reload.sh" "${RUN}" "${ROBOT_LIST}" || true

# dtif eval after the replay (the offline reference for the loops; not while the nodelets run).
if [ ! -f "${OUT}/eval/summary.json" ] || [ "${OUT}/simulated" -nt "${OUT}/eval/summary.json" ]; then
  echo "dtif soak: dtif eval on the dataset (the offline reference; ${OUT}/eval)"
  rm -rf "${OUT}/eval"
  "${DTIF_BIN}" eval "${OUT}/dataset" --out "${OUT}/eval" --quiet > "${OUT}/eval.log"
fi
"${DTIF_BIN}" score "${OUT}/dataset" --loops "${LOG}" --out "${RUN}/score" --eval "${OUT}/eval" \
  > "${RUN}/score.txt"
STATUS=0
/usr/bin/python3 "${DTIF_REPO}/scripts/soak_report.py" --dataset "${OUT}/dataset" \
  --eval "${OUT}/eval" --run "${RUN}" --bag-start "${BAG_START}" --played-s "${PLAY_S}" \
  --bag-s "${BAG_S}" --rate "${RATE}" --max-lag-s "${DTIF_SOAK_MAX_LAG_S:-1.0}" || STATUS=$?
grep -cE "WARN|ERROR|FATAL" "${RUN}/roslaunch.log" | xargs echo "dtif soak: warnings/errors in roslaunch.log:"
echo "dtif soak: done in $(( $(date +%s) - START_S )) s of wall time; results in ${RUN}"
exit "${STATUS}"
