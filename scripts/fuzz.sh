#!/usr/bin/env bash
# `make fuzz`: runs each libFuzzer target (fuzz/) for a bounded time from the seed corpus in fuzz/corpus.
# New inputs go to BUILD/fuzz-corpus (the repository's corpus is only read); a finding is written to
# BUILD/fuzz-findings/TARGET/ and makes the script fail. A finding worth keeping becomes a regression file:
# add it to fuzz/corpus/TARGET and a case to tests/test_hostile_input.cpp.
set -uo pipefail
build=${1:-build-fuzz}
seconds=${2:-60}
status=0
for target in ply pcd stl obj columns vtk job; do
  exe="$build/fuzz/fuzz_$target"
  [[ -x "$exe" ]] || { echo "fuzz: $exe is missing (make fuzz builds it)"; exit 2; }
  corpus="$build/fuzz-corpus/$target"
  findings="$build/fuzz-findings/$target"
  mkdir -p "$corpus" "$findings"
  echo "fuzz: $target for ${seconds} s"
  if ! (cd "$findings" && ASAN_OPTIONS=detect_leaks=1 "$OLDPWD/$exe" -max_total_time="$seconds" -timeout=10 \
          -rss_limit_mb=2048 -max_len=65536 -print_final_stats=1 "$OLDPWD/$corpus" "$OLDPWD/fuzz/corpus/$target" \
          > "$OLDPWD/$build/fuzz-$target.log" 2>&1); then
    echo "fuzz: $target found something: $findings (log $build/fuzz-$target.log)"
    status=1
  fi
  grep -E "^stat::number_of_executed_units|^Done" "$build/fuzz-$target.log" | tr '\n' ' '; echo
done
exit $status
