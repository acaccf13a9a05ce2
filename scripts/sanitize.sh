#!/usr/bin/env bash
# The gtest binaries (core, merge, io, eval, baselines, the tool's command line run as a
# process, the ROS glue) under AddressSanitizer and UndefinedBehaviorSanitizer (issue #17), in
# the workspace of their own that scripts/fuzz.sh shares (.ws-san: clang, -O1, so CI can afford
# it; common.sh's dtif_san_build). Any sanitizer finding fails the test that triggers it; exits
# non-zero then. The tests' random data and the simulator's are drawn one number per statement,
# so clang builds the same data as gcc and every test case runs here.
# Usage: bash scripts/sanitize.sh [gtest-binary-name...]   (default: the list below)
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
TESTS=("$@")
if [ ${#TESTS[@]} -eq 0 ]; then
  # Every gtest binary of test/CMakeLists.txt but the long suites, which run in scripts/test.sh
  # only: simulator_test and sim_bag_test (whole simulated surveys and bags), bag_submaps_test
  # (replays a simulated bag through the assembler: 9 min under ASan), loop_benchmark_test (a
  # benchmark) and the rostest nodes (they need a master). merge_cmd_test simulates its dataset
  # with `dtif simulate`, which draws one number per statement too, so clang simulates the same
  # forest as gcc (docs/limits.md).
  TESTS=(limits_test descriptor_test describe_test ground_map_test footprint_test gravity_test
    imu_gravity_test extraction_stages_test trunk_extractor_test trunk_accumulator_test
    loop_detector_test query_index_test
    elevation_test verification_test matcher_test pair_vote_test pose_estimator_test
    robot_links_test database_odometry_test voxel_grid_test lattice_test avx2_paths_test
    map_merger_test factor_cost_test stem_inventory_test stemmap_registration_test stem_map_anchor_test
    config_test dataset_test pcd_reader_test merge_files_test real_data_test evaluation_test
    fpfh_registration_test scan_context_test solvers_test cli_test
    bounded_queue_test conversions_test fleet_map_test submap_assembler_test frame_lock_test frames_test map_frames_test
    params_test markers_test merge_cmd_test)
fi
dtif_san_build "${TESTS[@]}"
# Leaks are reported too; the suppressions are third-party one-time allocations.
export ASAN_OPTIONS="detect_leaks=1:abort_on_error=0:strict_string_checks=1"
export LSAN_OPTIONS="suppressions=${DTIF_REPO}/scripts/lsan.supp:print_suppressions=0"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
# Two binaries at a time (common.sh's dtif_pool; each one is single-threaded), the slowest
# first so that neither core idles at the end: cli_test (~190 s under ASan), merge_cmd_test
# (~140 s), elevation_test (~80 s) run the tool or whole surveys; the rest take seconds.
ordered=()
for t in cli_test merge_cmd_test elevation_test "${TESTS[@]}"; do
  if [[ " ${TESTS[*]} " == *" ${t} "* && " ${ordered[*]} " != *" ${t} "* ]]; then
    ordered+=("${t}")
  fi
done
run_test() {
  "${DTIF_SAN_WS}/devel/lib/dtif/$1" --gtest_brief=1 > "${DTIF_SAN_WS}/$1.log" 2>&1
}
report_test() {
  if [ "$2" -eq 0 ]; then
    echo "sanitize: $1 ok"
  else
    echo "sanitize: $1 FAILED"; tail -40 "${DTIF_SAN_WS}/$1.log"; failed+=("$1")
  fi
}
failed=()
dtif_pool run_test report_test "${ordered[@]}"
if [ ${#failed[@]} -gt 0 ]; then
  echo "sanitize: ${#failed[@]} of ${#TESTS[@]} failed: ${failed[*]}"
  exit 1
fi
echo "sanitize: all ${#TESTS[@]} test binaries clean under ASan + UBSan"
