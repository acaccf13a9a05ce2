#!/usr/bin/env bash
# README command 1: sets everything up on a fresh Debian 12 machine, simulates a forest survey
# by several robots (built-in scene), runs the evaluation protocol on it and prints the
# paper-style table. Usage: scripts/demo.sh [scene.yaml] (default: config/scenes/mixed.yaml)
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
SCENE="${1:-${DTIF_REPO}/config/scenes/mixed.yaml}"
NAME="$(basename "${SCENE}" .yaml)"
OUT="${DTIF_WS}/demo/${NAME}"

dtif_build
echo "dtif demo: simulating ${SCENE} -> ${OUT}/dataset"
rm -rf "${OUT}"
"${DTIF_BIN}" simulate "${SCENE}" --out "${OUT}/dataset" --seed 1 --png "${OUT}/scene.png"
echo "dtif demo: evaluating (results in ${OUT}/eval)"
"${DTIF_BIN}" eval "${OUT}/dataset" --out "${OUT}/eval"
