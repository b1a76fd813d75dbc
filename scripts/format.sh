#!/usr/bin/env bash
# Formats every C++ source of the package with clang-format (.clang-format at
# the top). With --check it changes nothing and fails on any file that is not
# formatted, naming it (the `clang_format` test runs this).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
mapfile -t files < <(find include src test \( -name '*.cpp' -o -name '*.hpp' -o -name '*.h' \) | sort)
if [ "${1:-}" = "--check" ]; then
  bad=()
  for f in "${files[@]}"; do
    clang-format --dry-run -Werror "$f" >/dev/null 2>&1 || bad+=("$f")
  done
  if [ ${#bad[@]} -gt 0 ]; then
    echo "not clang-formatted (run scripts/format.sh): ${bad[*]}" >&2
    exit 1
  fi
  echo "all ${#files[@]} C++ files are clang-formatted"
else
  clang-format -i "${files[@]}"
fi
