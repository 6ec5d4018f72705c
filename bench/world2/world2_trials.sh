#!/bin/bash
# world2_trials.sh FIRST COUNT [--keep DIR] [--unit um|mm|m|in] [--sensor scanner|depthcam]
# Generates COUNT world-2 cells from seed FIRST, runs partloc on each and compares every scan with the
# truth (world2_compare.py states the tolerance). Environment: PARTLOC (default build/partloc),
# WORLD2 (default build/bench/world2/partloc_world2), relative to the repository root; WORLD2_OPTS
# (say --ideal: a perfect sensor) is passed to the generator; --sensor depthcam scans the same cells with a
# consumer depth camera (README, "The depth camera").
set -u
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
first=${1:?usage: world2_trials.sh FIRST COUNT [--keep DIR] [--unit U] [--sensor S]}
count=${2:?usage: world2_trials.sh FIRST COUNT [--keep DIR] [--unit U] [--sensor S]}
shift 2
keep="" unit=mm sensor=scanner
while [ $# -gt 0 ]; do
  case $1 in
    --keep) keep=$2; shift 2 ;;
    --unit) unit=$2; shift 2 ;;
    --sensor) sensor=$2; shift 2 ;;
    *) echo "world2_trials.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
partloc=${PARTLOC:-$root/build/partloc}
gen=${WORLD2:-$root/build/bench/world2/partloc_world2}
if [ -n "$keep" ]; then work=$keep; mkdir -p "$work"; else work=$(mktemp -d); trap 'rm -rf "$work"' EXIT; fi
seeds=()
# partloc's commit: the last one that touched its sources (this script's own commits do not change it)
echo "partloc $(git -C "$root" log -1 --format=%h -- src CMakeLists.txt 2>/dev/null) (tree $(git -C "$root" rev-parse --short HEAD 2>/dev/null), $partloc), world 2 generator $gen, seeds $first..$((first + count - 1)), unit $unit, sensor $sensor${WORLD2_OPTS:+, generator options $WORLD2_OPTS}"
for ((s = first; s < first + count; s++)); do
  d=$work/seed_$s
  rm -rf "$d"
  "$gen" --out "$d" --seed "$s" --unit "$unit" --sensor "$sensor" ${WORLD2_OPTS:-} > /dev/null || { echo "seed $s: generator failed" >&2; continue; }
  start=$(date +%s.%N)
  "$partloc" run "$d/job.yaml" --out "$d/out" --no-cache > "$d/partloc.log" 2>&1
  rc=$?
  printf 'seed %s: partloc exit %s, %.1f s\n' "$s" "$rc" "$(echo "$(date +%s.%N) - $start" | bc)"
  seeds+=("$s")
  # keep what the comparison needs, not the scans, unless --keep
  [ -n "$keep" ] || rm -rf "$d/scans" "$d/out/merged.ply" "$d/out/stock.stl" "$d/out/report.html"
done
echo
python3 "$here/world2_compare.py" "$work" "${seeds[@]}"
