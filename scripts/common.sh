# Shared settings of dtif's scripts (sourced, not run).
# Debian's ROS Python modules are only visible to /usr/bin/python3 (ROS_ON_DEBIAN.md #1).
export PATH="/usr/bin:/bin:/usr/sbin:/sbin:${PATH}"
DTIF_REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
DTIF_WS="${DTIF_WS:-${DTIF_REPO}/.ws}"
DTIF_JOBS="${DTIF_JOBS:-2}"
export ROS_HOME="${ROS_HOME:-${DTIF_WS}/ros_home}"
export ROS_LOG_DIR="${ROS_LOG_DIR:-${ROS_HOME}/log}"
export ROSCONSOLE_STDOUT_LINE_BUFFERED=1
DTIF_CMAKE_ARGS=(-DCMAKE_BUILD_TYPE=Release -DPYTHON_EXECUTABLE=/usr/bin/python3
  -DPython3_EXECUTABLE=/usr/bin/python3)
DTIF_BIN="${DTIF_WS}/devel/lib/dtif/dtif"

# Sets up the catkin workspace (src/dtif links to this repository) and builds dtif.
dtif_build() {
  bash "${DTIF_REPO}/scripts/install_deps.sh"
  mkdir -p "${DTIF_WS}/src" "${ROS_LOG_DIR}"
  if [ ! -e "${DTIF_WS}/src/dtif" ]; then
    ln -s "${DTIF_REPO}" "${DTIF_WS}/src/dtif"
  fi
  (cd "${DTIF_WS}" && catkin_make -j"${DTIF_JOBS}" "${DTIF_CMAKE_ARGS[@]}" "$@")
}
