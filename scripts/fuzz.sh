#!/usr/bin/env bash
# Runs every libFuzzer target of fuzz/ (issue #17) for a bounded time each, from the committed
# seeds (fuzz/corpus/<target>/), in the sanitizer workspace shared with scripts/sanitize.sh
# (clang, ASan + UBSan). New inputs go to a scratch corpus, never into the repository; a
# finding (crash, sanitizer report, leak, > 2 GB RSS, a > 20 s input) fails the script and
# leaves its reproducer in .ws-san/fuzz/<target>/.
# Usage: bash scripts/fuzz.sh [seconds per target, default 20] [target...]
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
SECONDS_EACH="${1:-20}"
shift || true
TARGETS=("$@")
if [ ${#TARGETS[@]} -eq 0 ]; then
  TARGETS=(fuzz_pcd fuzz_descriptor fuzz_database fuzz_ground_map fuzz_config fuzz_scene
    fuzz_csv fuzz_ros_msgs)
fi
dtif_san_build "${TARGETS[@]}"
export ASAN_OPTIONS="detect_leaks=1:allocator_may_return_null=0"
export LSAN_OPTIONS="suppressions=${DTIF_REPO}/scripts/lsan.supp:print_suppressions=0"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
# Two targets at a time (common.sh's dtif_pool; libFuzzer runs one thread), each in its own
# folder with its own log.
run_target() {
  local t="$1" out="${DTIF_SAN_WS}/fuzz/$1"
  rm -rf "${out}"
  mkdir -p "${out}/corpus"
  cd "${out}"
  "${DTIF_SAN_WS}/devel/lib/dtif/${t}" -seed=1 -max_total_time="${SECONDS_EACH}" \
    -timeout=20 -rss_limit_mb=2048 -max_len=65536 -print_final_stats=1 \
    -artifact_prefix="${out}/" corpus "${DTIF_REPO}/fuzz/corpus/${t#fuzz_}" > "${out}/fuzz.log" 2>&1
}
report_target() {
  local t="$1" out="${DTIF_SAN_WS}/fuzz/$1"
  if [ "$2" -eq 0 ]; then
    echo "fuzz: ${t} ok: $(grep -E '^#[0-9]+.*DONE' "${out}/fuzz.log" | tail -1)"
  else
    echo "fuzz: ${t} FAILED (reproducer in ${out}/)"; tail -40 "${out}/fuzz.log"; failed+=("${t}")
  fi
}
failed=()
dtif_pool run_target report_target "${TARGETS[@]}"
if [ ${#failed[@]} -gt 0 ]; then
  echo "fuzz: ${#failed[@]} of ${#TARGETS[@]} targets found a problem: ${failed[*]}"
  exit 1
fi
echo "fuzz: ${#TARGETS[@]} targets, ${SECONDS_EACH} s each, no finding"
