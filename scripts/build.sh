#!/usr/bin/env bash
# Installs dependencies, sets up the catkin workspace and builds dtif (idempotent).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
dtif_build
echo "dtif: built ${DTIF_BIN}"
