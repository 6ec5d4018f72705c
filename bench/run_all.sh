#!/usr/bin/env bash
# Regenerates BENCHMARK.md's tables: each method on each cell in its own process (so that peak memory is the
# method's own), then partloc's scaling. One job at a time: the figures are wall times.
#   bench/run_all.sh [build_dir] [out_dir]          all tables
#   PARTS="compare" bench/run_all.sh                only the comparison (PARTS: compare points scans)
#   SEEDS="101 106" METHODS="partloc" bench/run_all.sh
#   PARTS="rounds run" ROUNDS=4 bench/run_all.sh    the later sections' way (BENCHMARK.md, "State at 3076f09"):
#     rounds: on SCALING_SEED, ROUNDS rounds of partloc cold, partloc warm (from the model cache), Open3D and
#             the paper's pipeline, one after another, so that the machine's drift falls on all alike;
#     run:    `partloc run` end to end with the stock (simulated jobs of RUN_SEEDS), cold and warm
#             alternating, ROUNDS rounds, timed by /usr/bin/time.
#   SPACINGS="0.856 0.383 0.1915 0.1354 0.0606" PARTS=points bench/run_all.sh   up to 10 M points per scan
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
ROUNDS=${ROUNDS:-4}
RUN_SEEDS=${RUN_SEEDS:-"106 3"}
mkdir -p "$OUT"
CACHE=$(mktemp -d)  # partloc's model cache for the comparison's second runs
trap 'rm -rf "$CACHE"' EXIT
[ -x "$BENCH" ] || { echo "no $BENCH: build first (cmake --build $BUILD)" >&2; exit 2; }

header() { "$BENCH" header; }
fill_cache() {  # a first partloc run on seed $1, which leaves its fiducials' prepared models in $CACHE
  "$BENCH" compare --method partloc --seed "$1" --cache "$CACHE" > /dev/null 2>&1
}
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
        fill_cache "$s"
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
if [[ " $PARTS " == *" rounds "* ]]; then
  fill_cache "$SCALING_SEED"
  { header
    for r in $(seq 1 "$ROUNDS"); do
      run "$BENCH" compare --method partloc --seed "$SCALING_SEED"
      echo "# ^ partloc cold (no cache), round $r"
      run "$BENCH" compare --method partloc --seed "$SCALING_SEED" --cache "$CACHE"
      echo "# ^ partloc warm (--cache), round $r"
      for m in open3d paper; do
        [[ " $METHODS " == *" $m "* ]] && run "$BENCH" compare --method "$m" --seed "$SCALING_SEED"
      done
    done
  } | tee "$OUT/compare_rounds.txt"
fi
if [[ " $PARTS " == *" run "* ]]; then
  PARTLOC="$BUILD/partloc"
  JOBS=$(mktemp -d)
  { echo "# partloc run JOB --out DIR [--no-cache | --cache DIR] (with the stock), $ROUNDS rounds alternating;"
    echo "# columns: seed, cold/warm, wall s, user s, system s, peak KB (/usr/bin/time)"
    for s in $RUN_SEEDS; do
      "$PARTLOC" simulate --seed "$s" --out "$JOBS/j$s" > /dev/null
      "$PARTLOC" run "$JOBS/j$s/job.yaml" --out "$JOBS/out" --cache "$CACHE" > /dev/null 2>&1  # fills the cache
    done
    for r in $(seq 1 "$ROUNDS"); do for s in $RUN_SEEDS; do
      /usr/bin/time -f "$s cold %e %U %S %M" "$PARTLOC" run "$JOBS/j$s/job.yaml" --out "$JOBS/out" --no-cache 2>&1 > /dev/null | tail -1
      /usr/bin/time -f "$s warm %e %U %S %M" "$PARTLOC" run "$JOBS/j$s/job.yaml" --out "$JOBS/out" --cache "$CACHE" 2>&1 > /dev/null | tail -1
    done; done
  } | tee "$OUT/run_rounds.txt"
  rm -rf "$JOBS"
fi
