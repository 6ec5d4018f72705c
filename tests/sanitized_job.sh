#!/bin/sh
# One small job end to end through the sanitized command line (CMakeLists.txt, PARTLOC_SANITIZE_TESTS):
# simulate a job, run it, and check that it was located or said why not (exit 0 or 3) with result.json.
# A sanitizer's finding exits 1 (halt_on_error) and fails the test.
set -u
exe=$1
dir=$2
rm -rf "$dir"
"$exe" simulate --seed 3 --out "$dir/job" > /dev/null || exit 1
"$exe" run "$dir/job/job.yaml" --out "$dir/out" --no-cache --threads 2 > "$dir/run.txt" 2>&1
code=$?
cat "$dir/run.txt"
if [ "$code" -ne 0 ] && [ "$code" -ne 3 ]; then echo "exit $code"; exit 1; fi
[ -s "$dir/out/result.json" ] || { echo "no result.json"; exit 1; }
if grep -q "runtime error\|AddressSanitizer\|LeakSanitizer" "$dir/run.txt"; then exit 1; fi
exit 0
