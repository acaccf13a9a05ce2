# Shared settings of dtif's scripts (sourced, not run).
# Debian's ROS Python modules are only visible to /usr/bin/python3 (ROS_ON_DEBIAN.md #1).
export PATH="/usr/bin:/bin:/usr/sbin:/sbin:${PATH}"
DTIF_REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
DTIF_WS="${DTIF_WS:-${DTIF_REPO}/.ws}"
DTIF_JOBS="${DTIF_JOBS:-2}"
export ROS_HOME="${ROS_HOME:-${DTIF_WS}/ros_home}"
export ROS_LOG_DIR="${ROS_LOG_DIR:-${ROS_HOME}/log}"
export ROSCONSOLE_STDOUT_LINE_BUFFERED=1
# ccache (install_deps.sh installs it) makes a rebuild in a fresh clone or a new workspace quick.
# Paths under the repository are hashed relative to it and the working directory is left out of
# the hash, so clones in other folders (CI's, git worktrees) share one cache.
export CCACHE_BASEDIR="${CCACHE_BASEDIR:-${DTIF_REPO}}"
export CCACHE_NOHASHDIR="${CCACHE_NOHASHDIR:-1}"
DTIF_CCACHE_ARGS=(-DCMAKE_C_COMPILER_LAUNCHER=ccache -DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
DTIF_CMAKE_ARGS=(-DCMAKE_BUILD_TYPE=Release -DPYTHON_EXECUTABLE=/usr/bin/python3
  -DPython3_EXECUTABLE=/usr/bin/python3 "${DTIF_CCACHE_ARGS[@]}")
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

# dtif_build with its output in .ws/build.log, printed only when the build fails (then exits).
dtif_build_logged() {
  mkdir -p "${DTIF_WS}"
  dtif_build "$@" > "${DTIF_WS}/build.log" 2>&1 || { cat "${DTIF_WS}/build.log"; exit 1; }
}

# Sources the workspace (roslaunch, rosrun find dtif); catkin's setup script reads unset variables.
dtif_source_ws() {
  set +u
  source "${DTIF_WS}/devel/setup.bash"
  set -u
}

# A master of our own on a free port (other roscores on the machine are left alone): sets
# DTIF_PORT and exports ROS_MASTER_URI; pass -p "${DTIF_PORT}" to roslaunch.
dtif_private_master() {
  DTIF_PORT="$(/usr/bin/python3 -c 'import socket; s=socket.socket(); s.bind(("", 0)); print(s.getsockname()[1])')"
  export ROS_MASTER_URI="http://localhost:${DTIF_PORT}"
}

# ROBOTS: the robots of a dataset (submaps.csv), in order of first appearance.
dtif_robots() {
  mapfile -t ROBOTS < <(tail -n +2 "$1/submaps.csv" | cut -d, -f2 | awk '!seen[$0]++')
}

# SCENES: the scene YAMLs given as arguments, else every built-in scene (config/scenes/).
dtif_scenes() {
  SCENES=("$@")
  if [ ${#SCENES[@]} -eq 0 ]; then
    SCENES=("${DTIF_REPO}"/config/scenes/*.yaml)
  fi
}

# Simulates scene $1 with seed $3 (default 1) into $2/dataset, with $2/scene.png and
# $2/simulate.log, unless $2 holds a dataset of that seed newer than the scene file (the
# datasets of eval_scenes.sh and bench.sh).
dtif_scene_dataset() {
  local scene="$1" dir="$2" seed="${3:-1}"
  if [ ! -f "${dir}/dataset/submaps.csv" ] || [ "${scene}" -nt "${dir}/dataset/submaps.csv" ] \
    || [ "$(cat "${dir}/seed" 2>/dev/null || echo 1)" != "${seed}" ]; then
    rm -rf "${dir}"
    mkdir -p "${dir}"
    echo "== $(basename "${scene}" .yaml): simulating (seed ${seed})" >&2
    "${DTIF_BIN}" simulate "${scene}" --out "${dir}/dataset" --seed "${seed}" \
      --png "${dir}/scene.png" | tee "${dir}/simulate.log" >&2
    echo "${seed}" > "${dir}/seed"
  fi
}

# Builds the given targets in the sanitizer workspace (.ws-san) shared by scripts/sanitize.sh
# and scripts/fuzz.sh: clang, -O1, AddressSanitizer + UndefinedBehaviorSanitizer, libFuzzer's
# coverage instrumentation (harmless for the unit tests), the fuzz targets enabled. The build
# log is .ws-san/build.log, printed when the build fails (then exits). The targets are built as
# one goal, dtif_goal (CMakeLists.txt), so that make runs DTIF_JOBS compilers on them at once.
DTIF_SAN_WS="${DTIF_SAN_WS:-${DTIF_REPO}/.ws-san}"
dtif_san_build() {
  # -gline-tables-only: the file:line (inlined frames included) of the sanitizers' stack
  # traces, without the variables' debug info that a debugger needs (as OSS-Fuzz builds);
  # clang's compile time drops by ~30-40 % (dataset_test.cpp 17 -> 12 s, map_merger.cpp 56 ->
  # 33 s of CPU) and the objects by 2-4x. ASan names a stack frame's variables from its own
  # instrumentation, and UBSan's source locations are compiled in: reports stay the same.
  local flags="-O1 -gline-tables-only -fno-omit-frame-pointer"
  flags+=" -fsanitize=address,undefined,fuzzer-no-link -fno-sanitize-recover=all"
  bash "${DTIF_REPO}/scripts/install_deps.sh"
  mkdir -p "${DTIF_SAN_WS}/src"
  [ -e "${DTIF_SAN_WS}/src/dtif" ] || ln -s "${DTIF_REPO}" "${DTIF_SAN_WS}/src/dtif"
  # A build type of its own: Release's -O3 -DNDEBUG would override the flags (asserts stay on).
  (cd "${DTIF_SAN_WS}" && CC="${DTIF_SAN_CC:-clang}" CXX="${DTIF_SAN_CXX:-clang++}" \
    catkin_make -j"${DTIF_JOBS}" -DCMAKE_BUILD_TYPE=Sanitize -DDTIF_FUZZ=ON "${DTIF_CCACHE_ARGS[@]}" \
    -DCMAKE_C_FLAGS_SANITIZE="${flags}" -DCMAKE_CXX_FLAGS_SANITIZE="${flags}" \
    -DCMAKE_EXE_LINKER_FLAGS_SANITIZE="-fsanitize=address,undefined" \
    -DCMAKE_SHARED_LINKER_FLAGS_SANITIZE="-fsanitize=address,undefined" \
    -DPYTHON_EXECUTABLE=/usr/bin/python3 -DPython3_EXECUTABLE=/usr/bin/python3 \
    -DDTIF_GOAL_TARGETS="$(IFS=';'; echo "$*")" dtif_goal \
    > "${DTIF_SAN_WS}/build.log" 2>&1) || { tail -60 "${DTIF_SAN_WS}/build.log"; exit 1; }
}

# dtif_pool <run> <report> <item...>: runs "<run> <item>" for every item in the background,
# DTIF_JOBS at a time, in the order given (so put the slowest first); as each one ends, this
# shell runs "<report> <item> <exit status>", so reports come one at a time and never
# interleave (scripts/sanitize.sh and scripts/fuzz.sh: their test binaries and fuzz targets are
# single-threaded, and CI's machine has 2 cores).
dtif_pool() {
  local run="$1" report="$2" item pid status
  shift 2
  local -A running=()  # pid -> item
  for item in "$@" ""; do
    # Wait for a free slot (after the last item: for all of them).
    while [ "${#running[@]}" -gt 0 ] \
        && { [ -z "${item}" ] || [ "${#running[@]}" -ge "${DTIF_JOBS}" ]; }; do
      status=0
      wait -n -p pid "${!running[@]}" || status=$?
      "${report}" "${running[${pid}]}" "${status}"
      unset "running[${pid}]"
    done
    [ -z "${item}" ] && break
    "${run}" "${item}" &
    running[$!]="${item}"
  done
}
