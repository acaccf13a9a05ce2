#!/usr/bin/env bash
# README command 2: sets everything up on a fresh Debian 12 machine and runs every test.
# Ends with ctest's summary line; exits non-zero when any test fails.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
dtif_build
(cd "${DTIF_WS}" && catkin_make -j"${DTIF_JOBS}" "${DTIF_CMAKE_ARGS[@]}" tests)
cd "${DTIF_WS}/build"
# DTIF_JOBS tests at a time: the gtests are plain processes (their scratch folders carry their
# pid); the rostests run alone (RUN_SERIAL, test/CMakeLists.txt). -j1 as an argument overrides.
ctest --output-on-failure --timeout 600 -j"${DTIF_JOBS}" "$@"
