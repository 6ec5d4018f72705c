#!/usr/bin/env bash
# Fails, naming the files, when a C++ source differs from the checked-in .clang-format (a check, never a
# rewrite: `clang-format -i FILE` formats one). Run by ctest as format_check.
set -uo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
command -v clang-format > /dev/null || { echo "clang-format not found (scripts/install-deps.sh installs it)"; exit 1; }
files=$(git ls-files '*.cpp' '*.hpp' '*.h' 2> /dev/null || find src tests bench examples -name '*.[ch]pp')
bad=()
for f in $files; do
  [[ -f "$f" ]] || continue
  clang-format --dry-run -Werror "$f" > /dev/null 2>&1 || bad+=("$f")
done
if ((${#bad[@]})); then
  echo "not formatted by .clang-format (${#bad[@]} files): ${bad[*]}"
  exit 1
fi
