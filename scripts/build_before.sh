#!/usr/bin/env bash
# Builds the speed probe (dtif_query_bench, src/tool/query_bench.cpp) against the library of an
# earlier commit, so that scripts/bench_speed.sh measures "before" and "after" with the same
# instrument. The commit's tree is exported (git archive, no worktree) into .ws/before/<commit>,
# this checkout's probe source is copied in, and only the probe and what it links are built.
# Usage: scripts/build_before.sh [commit]   (default 7bc3e70: main when issue #18 started)
# Prints the probe's path. Idempotent: a second call rebuilds only what changed.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
COMMIT="$(git -C "${DTIF_REPO}" rev-parse --short "${1:-7bc3e70}")"
BWS="${DTIF_WS}/before/${COMMIT}"
SRC="${BWS}/src/dtif"
if [ ! -e "${SRC}/package.xml" ]; then
  mkdir -p "${SRC}"
  git -C "${DTIF_REPO}" archive "${COMMIT}" | tar -x -C "${SRC}"
fi
# The probe: the same source as this checkout's, whatever the commit had.
cp "${DTIF_REPO}/src/tool/query_bench.cpp" "${DTIF_REPO}/src/tool/proc_status.h" "${SRC}/src/tool/"
if ! grep -q "dtif_query_bench" "${SRC}/src/tool/CMakeLists.txt"; then
  cat >> "${SRC}/src/tool/CMakeLists.txt" << 'EOF'

# Added by scripts/build_before.sh: the speed probe of the checkout that measures this commit.
add_executable(dtif_query_bench query_bench.cpp)
target_link_libraries(dtif_query_bench PRIVATE dtif_baselines)
set_target_properties(dtif_query_bench PROPERTIES
  RUNTIME_OUTPUT_DIRECTORY ${CATKIN_DEVEL_PREFIX}/${CATKIN_PACKAGE_BIN_DESTINATION})
EOF
fi
bash "${DTIF_REPO}/scripts/install_deps.sh"
# Tests off: only the probe and the libraries it links.
(cd "${BWS}" && catkin_make -j"${DTIF_JOBS}" "${DTIF_CMAKE_ARGS[@]}" -DCATKIN_ENABLE_TESTING=OFF \
  dtif_query_bench) > "${BWS}/build.log" 2>&1 || {
  tail -50 "${BWS}/build.log"
  exit 1
}
echo "${BWS}/devel/lib/dtif/dtif_query_bench"
