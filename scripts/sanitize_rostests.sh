#!/usr/bin/env bash
# The rostests (test/*.test) under AddressSanitizer + UndefinedBehaviorSanitizer (issue #17),
# which scripts/sanitize.sh leaves out because they need a master. The nodelets, the plain
# nodes, the tool (the rostest nodes simulate their bags with it) and the rostest nodes are built
# by gcc with the sanitizers in a workspace of their own (.ws-san-ros); rostest then runs with
# gcc's shared ASan runtime preloaded into every process: the nodelet manager is ROS's own
# uninstrumented binary that loads our plugin library, and the Python processes (rostest,
# roslaunch, rosmaster) only carry the runtime, so leak checks are off. Every sanitizer report
# goes to a file in .ws-san-ros/reports; any report fails the run, as does a failing rostest.
# Not in CI (a cold build and the five rostests take ~30 min on 2 cores): run it after changes
# to the ROS glue. Usage: bash scripts/sanitize_rostests.sh [name.test ...]  (default: all);
# DTIF_SAN_ROS_CC / DTIF_SAN_ROS_CXX: the compilers (default gcc / g++, e.g. ccache's wrappers).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
WS="${DTIF_REPO}/.ws-san-ros"
TESTS=("$@")
if [ ${#TESTS[@]} -eq 0 ]; then
  for t in "${DTIF_REPO}"/test/*.test; do TESTS+=("$(basename "${t}")"); done
fi
NODES=(demo_bag_rostest fleet_bags_rostest loop_closure_rostest map_merge_rostest
  relocalisation_rostest)

bash "${DTIF_REPO}/scripts/install_deps.sh"
mkdir -p "${WS}/src"
[ -e "${WS}/src/dtif" ] || ln -s "${DTIF_REPO}" "${WS}/src/dtif"
flags="-O1 -g -fno-omit-frame-pointer -fsanitize=address,undefined -fno-sanitize-recover=all"
echo "sanitize_rostests: building in ${WS} (log: ${WS}/build.log)"
(cd "${WS}" && CC="${DTIF_SAN_ROS_CC:-gcc}" CXX="${DTIF_SAN_ROS_CXX:-g++}" \
  catkin_make -j"${DTIF_JOBS}" -DCMAKE_BUILD_TYPE=Sanitize \
  -DCMAKE_C_FLAGS_SANITIZE="${flags}" -DCMAKE_CXX_FLAGS_SANITIZE="${flags}" \
  -DCMAKE_EXE_LINKER_FLAGS_SANITIZE="-fsanitize=address,undefined" \
  -DCMAKE_SHARED_LINKER_FLAGS_SANITIZE="-fsanitize=address,undefined" \
  -DPYTHON_EXECUTABLE=/usr/bin/python3 -DPython3_EXECUTABLE=/usr/bin/python3 \
  dtif_nodelets dtif trunk_extraction_node loop_closure_node "${NODES[@]}" \
  > "${WS}/build.log" 2>&1) || { tail -60 "${WS}/build.log"; exit 1; }

set +u
source "${WS}/devel/setup.bash"
set -u
REPORTS="${WS}/reports"
rm -rf "${REPORTS}"
mkdir -p "${REPORTS}"
export LD_PRELOAD="$(gcc -print-file-name=libasan.so)"
export ASAN_OPTIONS="detect_leaks=0:log_path=${REPORTS}/asan:strict_string_checks=1"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1:log_path=${REPORTS}/ubsan"
failed=()
for t in "${TESTS[@]}"; do
  echo "sanitize_rostests: ${t}"
  if ! rostest dtif "${t}" > "${WS}/${t%.test}.log" 2>&1 \
      || ! grep -q "RESULT: SUCCESS" "${WS}/${t%.test}.log"; then
    tail -30 "${WS}/${t%.test}.log"
    failed+=("${t}")
  fi
  if [ -n "$(ls -A "${REPORTS}")" ]; then
    echo "sanitize_rostests: ${t}: sanitizer reports:"
    head -60 "${REPORTS}"/*
    failed+=("${t} (sanitizer)")
    mkdir -p "${REPORTS}.${t%.test}" && mv "${REPORTS}"/* "${REPORTS}.${t%.test}/"
  fi
done
if [ ${#failed[@]} -gt 0 ]; then
  echo "sanitize_rostests: ${#failed[@]} failed: ${failed[*]}"
  exit 1
fi
echo "sanitize_rostests: all ${#TESTS[@]} rostests pass under ASan + UBSan, no sanitizer report"
