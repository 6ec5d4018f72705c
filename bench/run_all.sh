#!/usr/bin/env bash
# Regenerates BENCHMARK.md's tables: each method on each cell in its own process (so that peak memory is the
# method's own), then partloc's scaling. One job at a time: the figures are wall times.
#   bench/run_all.sh [build_dir] [out_dir]          all tables
#   PARTS="compare" bench/run_all.sh                only the comparison (PARTS: compare points scans)
#   SEEDS="101 106" METHODS="partloc" bench/run_all.sh
set -u
BUILD=${1:-build}
OUT=${2:-bench/results}
BENCH="$BUILD/bench/partloc_bench"
SEEDS=${SEEDS:-"101 102 106"}
METHODS=${METHODS:-"partloc open3d paper"}
PARTS=${PARTS:-"compare points scans"}
SCALING_SEED=${SCALING_SEED:-106}
SPACINGS=${SPACINGS:-"0.856 0.383 0.1915 0.1354"}  # about 50 k, 250 k, 1 M, 2 M points per scan
PER_POSITION=${PER_POSITION:-"2 4 10 20"}          # 6, 12, 30, 60 scans (three A positions)
mkdir -p "$OUT"
CACHE=$(mktemp -d)  # partloc's model cache for the comparison's second runs
trap 'rm -rf "$CACHE"' EXIT
[ -x "$BENCH" ] || { echo "no $BENCH: build first (cmake --build $BUILD)" >&2; exit 2; }

header() { "$BENCH" header; }
run() {  # one row; a failed process still leaves a line saying so
    local out
    out=$("$@" 2>&1); local rc=$?
    echo "$out" | grep -v '^$'
    [ $rc -eq 0 ] || [ $rc -eq 4 ] || echo "# exit $rc: $*"
}

{
  echo "# $(date -u +%Y-%m-%dT%H:%MZ)  $(nproc) cores  $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
} > "$OUT/machine.txt"

if [[ " $PARTS " == *" compare "* ]]; then
  { header
    for s in $SEEDS; do for m in $METHODS; do
      run "$BENCH" compare --method "$m" --seed "$s"
      if [ "$m" = partloc ]; then
        # Again as the second job with these fiducials: their prepared models read from the model cache
        # (the row's note says "model cache ...: N read"); a first run fills it.
        "$BENCH" compare --method partloc --seed "$s" --cache "$CACHE" > /dev/null 2>&1
        run "$BENCH" compare --method partloc --seed "$s" --cache "$CACHE"
      fi
    done; done
  } | tee "$OUT/compare.txt"
fi
if [[ " $PARTS " == *" points "* ]]; then
  { header
    for sp in $SPACINGS; do run "$BENCH" scaling --seed "$SCALING_SEED" --spacing "$sp"; done
  } | tee "$OUT/scaling_points.txt"
fi
if [[ " $PARTS " == *" scans "* ]]; then
  { header
    for k in $PER_POSITION; do run "$BENCH" scaling --seed "$SCALING_SEED" --per-position "$k"; done
  } | tee "$OUT/scaling_scans.txt"
fi
