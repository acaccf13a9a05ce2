#!/usr/bin/env bash
# Takes the README's picture of the merged map in rviz (docs/merge_rviz.png), headless: the
# bag-replay demo with the map merge (rviz/map.rviz, fixed frame `map`, the scene's robot names
# filled in; the merged cloud off: its canopy would hide the loops) under Xvfb with software
# OpenGL, then a screenshot of the virtual screen (ImageMagick's import). The camera looks down on the
# part of the plot with the most inter-robot loops (from dtif merge on the same dataset, whose map
# frame is the nodelet's: both start at the first robot's first submap), ~50 m across, so the loop
# edges can be told apart. Installs rviz, xvfb and imagemagick like scripts/screenshot.sh.
# Usage: scripts/screenshot_map.sh [scene.yaml] [out.png]
#   (default config/scenes/mixed.yaml, docs/merge_rviz.png; reuses scripts/demo.sh's bag)
# Environment: DTIF_SHOT_RATE (replay rate, default 2).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
SCENE="${1:-${DTIF_REPO}/config/scenes/mixed.yaml}"
PNG="${2:-${DTIF_REPO}/docs/merge_rviz.png}"
RATE="${DTIF_SHOT_RATE:-2}"
NAME="$(basename "${SCENE}" .yaml)"
OUT="${DTIF_WS}/demo/${NAME}"

bash "${DTIF_REPO}/scripts/install_deps.sh" rviz xvfb imagemagick libgl1-mesa-dri
dtif_build_logged
dtif_source_ws
if [ ! -f "${OUT}/${NAME}.bag" ] || [ ! -f "${OUT}/dataset/submaps.csv" ]; then
  rm -rf "${OUT}"
  "${DTIF_BIN}" simulate "${SCENE}" --out "${OUT}/dataset" --seed 1 --bag "${OUT}/${NAME}.bag"
fi
dtif_robots "${OUT}/dataset"
SHOT="${OUT}/screenshot_map"
rm -rf "${SHOT}"
mkdir -p "${SHOT}"
"${DTIF_BIN}" merge "${OUT}/dataset" --out "${SHOT}/merge" --quiet > "${SHOT}/merge.txt"
# The focus: the inter-robot loop (g2o edge between two robots' submaps) with the most other
# inter-robot loops within 20 m of its midpoint.
FOCUS="$(/usr/bin/python3 - "${SHOT}/merge" <<'PY'
import csv, sys
d = sys.argv[1]
pose = {r["id"]: (float(r["tx"]), float(r["ty"]), float(r["tz"]), r["robot"])
        for r in csv.DictReader(open(d + "/merged_poses.csv"))}
mids = []
for line in open(d + "/pose_graph.g2o"):
    f = line.split()
    if f and f[0].startswith("EDGE_SE3") and f[1] in pose and f[2] in pose:
        a, b = pose[f[1]], pose[f[2]]
        if a[3] != b[3]:
            mids.append([(a[i] + b[i]) / 2 for i in range(3)])
if not mids:
    mids = [[p[0], p[1], p[2]] for p in pose.values()]
near = lambda m: sum((m[0] - o[0]) ** 2 + (m[1] - o[1]) ** 2 < 400 for o in mids)
best = max(mids, key=near)
print("{X: %.1f, Y: %.1f, Z: %.1f}" % tuple(best))
PY
)"
echo "dtif screenshot: camera on ${FOCUS} in map"
sed -e "s#robot1#${ROBOTS[0]}#g" -e "s#robot2#${ROBOTS[1]:-robot2}#g" \
  -e "s#robot3#${ROBOTS[2]:-robot3}#g" -e "s#Focal Point: .*#Focal Point: ${FOCUS}#" \
  -e "s#Distance: .*#Distance: 60#" -e "s#Pitch: .*#Pitch: 1.4#" \
  "${DTIF_REPO}/rviz/map.rviz" > "${SHOT}/map.rviz"

DISPLAY_NUM=$((90 + RANDOM % 100))
dtif_private_master
export DISPLAY=":${DISPLAY_NUM}" LIBGL_ALWAYS_SOFTWARE=1
PIDS=()
cleanup() {
  for ((i = ${#PIDS[@]} - 1; i >= 0; i--)); do kill -INT "${PIDS[i]}" 2>/dev/null || true; done
  wait 2>/dev/null || true
}
trap cleanup EXIT
Xvfb "${DISPLAY}" -screen 0 1400x900x24 -nolisten tcp > "${SHOT}/xvfb.log" 2>&1 &
PIDS+=($!)
roslaunch -p "${DTIF_PORT}" dtif demo_bag.launch play:=false headless:=false bond:=false \
  robot1:="${ROBOTS[0]}" robot2:="${ROBOTS[1]:-}" robot3:="${ROBOTS[2]:-}" \
  rviz_config:="${SHOT}/map.rviz" > "${SHOT}/roslaunch.log" 2>&1 &
PIDS+=($!)
for _ in $(seq 1 120); do
  rostopic info /map_merge/markers 2>/dev/null | sed -n '/Subscribers:/,$p' | grep -q rviz && break
  sleep 0.5
done
sleep 3  # rviz draws its first frame
echo "dtif screenshot: playing ${OUT}/${NAME}.bag at rate ${RATE}"
rosbag play --clock --quiet --delay 2 --rate "${RATE}" "${OUT}/${NAME}.bag"  # as in demo.sh
sleep 8  # the last submaps, loops and solve
import -window root "${PNG}"
echo "dtif screenshot: ${PNG}"
