#!/usr/bin/env bash
# Installs every Debian package dtif needs to build, test and run its demo, and the packages
# named as arguments (other scripts' extras, e.g. scripts/screenshot.sh's rviz).
# Idempotent: returns at once when everything is already installed.
set -euo pipefail

PKGS=(
  build-essential cmake clang-format ccache
  clang libclang-rt-14-dev
  ros-core-dev catkin libnodeletlib-dev libnodelet-dev libnodeletlib-tools
  libpcl-ros-dev libpcl-conversions-dev libpcl-dev libcgal-dev libeigen3-dev
  libtf2-ros-dev libtf2-eigen-dev librosbag-dev python3-rosbag python3-rostest python3-roslaunch
  python3-rostopic ros-message-generation ros-sensor-msgs ros-geometry-msgs ros-visualization-msgs
  ros-std-msgs ros-nav-msgs ros-tf2-msgs libgtest-dev googletest rosbash libstd-srvs-dev python3-std-srvs
  python3-sensor-msgs python3-geometry-msgs python3-visualization-msgs python3-nav-msgs
  libyaml-cpp-dev nlohmann-json3-dev libpng-dev zlib1g-dev libcli11-dev librosbag-storage-dev
  libceres-dev libsuitesparse-dev
)

PKGS+=("$@")
missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
echo "dtif: installing ${#missing[@]} Debian packages: ${missing[*]}"
$SUDO apt-get update -q
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q -o DPkg::Lock::Timeout=900 \
  --no-install-recommends "${missing[@]}"
