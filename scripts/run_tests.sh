#!/usr/bin/env bash
# Installs what is missing, builds, and runs every test (module gtests, golden
# parity runs, rostests) through ctest. Exits non-zero if any test fails.
# (`catkin_make run_tests` would exit 0 on failures; ctest does not.)
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

"$LONG3R_ROOT/scripts/install_deps.sh"
"$LONG3R_ROOT/scripts/build.sh" all tests

# shellcheck disable=SC1091
set +u; source "$LONG3R_WS/devel/setup.bash"; set -u
cd "$LONG3R_WS/build"
ctest --output-on-failure --timeout 1800 "$@"
