#!/usr/bin/env bash
# The memory of the soak test's database on its own (scripts/soak.sh runs it after the replay):
# a fresh base station (loop closure + map merge in one nodelet manager, as in the run) loads the
# database the run saved and solves the map from it; its resident memory then is what the run's
# state takes, without anything the run's hour of queries may have left behind. soak_report.py
# compares it with the run's last samples.
# Usage: scripts/soak_reload.sh <run_dir> robot1,robot2,...   (needs <run_dir>/database.bin;
# writes <run_dir>/reload.csv: wall time, VmRSS kB, VmHWM kB, fds, threads, every 2 s for 20 s
# once the map merge is up to date, and reload_up_to_date). Environment:
# DTIF_SOAK_RELOAD_WAIT_S (default 120): the longest wait for the map merge.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
RUN="$1"
ROBOT_LIST="$2"
dtif_source_ws
dtif_private_master
roslaunch -p "${DTIF_PORT}" dtif base_station.launch robots:="[${ROBOT_LIST}]" bond:=false \
  headless:=true merge:=true database_file:="${RUN}/database.bin" \
  > "${RUN}/reload_roslaunch.log" 2>&1 &
LAUNCH_PID=$!
trap 'kill -INT ${LAUNCH_PID} 2>/dev/null || true' EXIT
# Up to date: the map merge answers and has solved everything it loaded (it may not within
# DTIF_SOAK_RELOAD_WAIT_S: a solve can hold the map for longer; the memory is sampled anyway,
# once the loop closure holds the whole database).
UP_TO_DATE=false
DEADLINE=$(( $(date +%s) + ${DTIF_SOAK_RELOAD_WAIT_S:-120} ))
while [ "$(date +%s)" -lt "${DEADLINE}" ]; do
  if timeout -k 2 10 rosservice call /map_merge/get_map_info 2>/dev/null | grep -q "up_to_date: True"
  then
    UP_TO_DATE=true
    break
  fi
  kill -0 "${LAUNCH_PID}" 2>/dev/null || break
  sleep 1
done
timeout -k 2 30 rosservice call /map_merge/get_map_info > "${RUN}/reload_map_info.yaml" 2>&1 || true
timeout -k 2 30 rosservice call /loop_closure/database_size > "${RUN}/reload_database_size.yaml" 2>&1 \
  || true
PID="$(pgrep -P "${LAUNCH_PID}" -f "__name:=dtif_manager" | head -1)"
echo "wall_time,rss_kb,hwm_kb,fds,threads" > "${RUN}/reload.csv"
for _ in $(seq 1 10); do
  echo "$(date +%s.%N),$(awk '/^VmRSS/ {r=$2} /^VmHWM/ {h=$2} /^Threads/ {t=$2}
    END {printf "%d,%d", r, h; printf ",%s,%d", "FDS", t}' "/proc/${PID}/status" \
    | sed "s/FDS/$(ls "/proc/${PID}/fd" | wc -l)/")" >> "${RUN}/reload.csv"
  sleep 2
done
kill -INT "${LAUNCH_PID}" 2>/dev/null || true
wait "${LAUNCH_PID}" 2>/dev/null || true
trap - EXIT
echo "${UP_TO_DATE}" > "${RUN}/reload_up_to_date"
echo "dtif soak: the database reloaded into a fresh base station: $(tail -1 "${RUN}/reload.csv" \
  | cut -d, -f2 | awk '{printf "%.0f", $1 / 1024}') MB resident (${RUN}/reload.csv; map merge up to" \
  "date: ${UP_TO_DATE})"
