#!/usr/bin/env bash
# Takes the README's picture of rviz on the bag-replay demo (docs/demo_rviz.png), headless:
# rviz (rviz/dtif.rviz, the scene's robot names filled in, submap clouds shown) under Xvfb with
# software OpenGL, roslaunch dtif demo_bag.launch on the scene's bag, a screenshot of the
# virtual screen (ImageMagick's import) once the bag has played. Installs the Debian packages it
# needs (rviz, xvfb, imagemagick) besides scripts/install_deps.sh's, through that script.
# Usage: scripts/screenshot.sh [scene.yaml] [out.png]
#   (default config/scenes/mixed.yaml, docs/demo_rviz.png; reuses scripts/demo.sh's bag)
# Environment: DTIF_SHOT_RATE (replay rate, default 2).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
SCENE="${1:-${DTIF_REPO}/config/scenes/mixed.yaml}"
PNG="${2:-${DTIF_REPO}/docs/demo_rviz.png}"
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
SHOT="${OUT}/screenshot"
rm -rf "${SHOT}"
mkdir -p "${SHOT}"
# The camera looks at the centre of all submaps, in robot1's odometry frame (the fixed frame):
# ground truth T_W_S of robot1's first submap and its T_O_S give T_W_O1.
FOCUS="$(/usr/bin/python3 - "${OUT}/dataset" <<'PY'
import csv, sys
def rot(q, v):  # rotate v by unit quaternion q = (x, y, z, w)
    x, y, z, w = q
    t = [2 * (y * v[2] - z * v[1]), 2 * (z * v[0] - x * v[2]), 2 * (x * v[1] - y * v[0])]
    return [v[0] + w * t[0] + y * t[2] - z * t[1], v[1] + w * t[1] + z * t[0] - x * t[2],
            v[2] + w * t[2] + x * t[1] - y * t[0]]
rows = list(csv.DictReader(open(sys.argv[1] + "/submaps.csv")))
gt = {r["id"]: r for r in csv.DictReader(open(sys.argv[1] + "/ground_truth.csv"))}
f = rows[0]
g = gt[f["id"]]
q_ws = [float(g[k]) for k in ("qx", "qy", "qz", "qw")]
q_os = [float(f["odom_" + k]) for k in ("qx", "qy", "qz", "qw")]
t_ws = [float(g[k]) for k in ("tx", "ty", "tz")]
t_os = [float(f["odom_" + k]) for k in ("tx", "ty", "tz")]
inv = lambda q: [-q[0], -q[1], -q[2], q[3]]
c = [sum(float(gt[r["id"]][k]) for r in rows) / len(rows) for k in ("tx", "ty", "tz")]
p_s = rot(inv(q_ws), [c[i] - t_ws[i] for i in range(3)])  # centre in S of that submap
p_o = [a + b for a, b in zip(rot(q_os, p_s), t_os)]        # ... in O1
print("{X: %.1f, Y: %.1f, Z: %.1f}" % tuple(p_o))
PY
)"
# The shipped rviz config (any number of robots; the fixed frame comes from the launch file) with
# the submap clouds on.
sed -e '/PointCloud2/,/Topic/s/Enabled: false/Enabled: true/' \
  -e "s#Focal Point: .*#Focal Point: ${FOCUS}#" \
  "${DTIF_REPO}/rviz/dtif.rviz" > "${SHOT}/demo.rviz"

# A private X display and master; everything started here is stopped on exit.
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
  publish_submap_cloud:=true rviz_config:="${SHOT}/demo.rviz" > "${SHOT}/roslaunch.log" 2>&1 &
PIDS+=($!)
for _ in $(seq 1 120); do
  rostopic info /markers 2>/dev/null | sed -n '/Subscribers:/,$p' | grep -q rviz && break
  sleep 0.5
done
sleep 3  # rviz draws its first frame
echo "dtif screenshot: playing ${OUT}/${NAME}.bag at rate ${RATE}"
rosbag play --clock --quiet --delay 2 --rate "${RATE}" "${OUT}/${NAME}.bag"  # as in demo.sh
sleep 5  # the last submaps and loop markers
import -window root "${PNG}"
echo "dtif screenshot: ${PNG}"
