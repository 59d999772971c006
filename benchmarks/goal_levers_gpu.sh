#!/usr/bin/env bash
# The goal module's levers beyond the CPU budget, trained on one CUDA GPU: every (lever, benchmark) pair of
# benchmarks/goal_levers.py's GPU levers as its own one-thread process, several at a time, each scored on its
# benchmark's whole validation part. Rows go to $OUT/goal_levers_gpu.csv, each run's log to $OUT/logs.txt, and
# each lever's trained goal U-Nets to $OUT/<lever>.tar (for scoring their goals downstream on a CPU).
#
#   OUT=/tmp/levers ROOT=/tmp/levers_store JOBS=10 LIMIT_S=420 bash benchmarks/goal_levers_gpu.sh
#
# ROOT may hold tracks/, windows/ and maps/ artifacts to start from (copied into every lever's store).
# Every run stops LIMIT_S seconds after this script started (a run not yet started then is skipped); a stopped
# run's log keeps the epochs it finished.
set -uo pipefail
OUT=${OUT:?set OUT}
ROOT=${ROOT:?set ROOT}
JOBS=${JOBS:-10}
LIMIT_S=${LIMIT_S:-420}
LEVERS=${LEVERS:-"profile steps_4x_more goalsar_widths goalsar_widths_steps_4x steps_16x_more"}
BENCHMARKS=${BENCHMARKS:-"eth hotel univ zara1 zara2"}
DEVICE=${DEVICE:-cuda}
EXTRA=${EXTRA:-}  # more goal_levers.py arguments, e.g. "--set goal.epochs=1" for a smoke run
mkdir -p "$OUT" "$ROOT/runs"
DEADLINE=$(($(date +%s) + LIMIT_S))

for lever in $LEVERS; do
  mkdir -p "$ROOT/$lever"
  for kind in tracks windows maps; do
    [ -d "$ROOT/$kind" ] && cp -r --update=none "$ROOT/$kind" "$ROOT/$lever/"
  done
done

run_one() {  # lever benchmark
  local left=$((DEADLINE - $(date +%s)))
  [ "$left" -gt 30 ] || { echo "$1 $2 skipped: no time left" >"$ROOT/runs/$1_$2.log"; return; }
  OMP_NUM_THREADS=1 PYTHONUNBUFFERED=1 timeout "$left" python3 benchmarks/goal_levers.py --device "$DEVICE" $EXTRA \
    --lever "$1" --benchmarks "$2" --root "$ROOT" --out "$ROOT/runs/$1_$2.csv" >"$ROOT/runs/$1_$2.log" 2>&1
  echo "$1 $2 exit $?" >>"$ROOT/runs/$1_$2.log"
}
export -f run_one
export ROOT DEADLINE DEVICE EXTRA
for lever in $LEVERS; do for benchmark in $BENCHMARKS; do echo "$lever $benchmark"; done; done |
  xargs -P "$JOBS" -L 1 bash -c 'run_one $0 $1'

first=1
for csv in "$ROOT"/runs/*.csv; do
  [ -e "$csv" ] || continue
  if [ $first = 1 ]; then cat "$csv"; first=0; else tail -n +2 "$csv"; fi
done >"$OUT/goal_levers_gpu.csv"
for log in "$ROOT"/runs/*.log; do echo "=== $log"; tr '\r' '\n' <"$log" | grep -v "━" ; done >"$OUT/logs.txt"
for lever in $LEVERS; do
  [ -d "$ROOT/$lever/goal" ] && tar -cf "$OUT/$lever.tar" -C "$ROOT/$lever" goal
done
wc -l "$OUT/goal_levers_gpu.csv"
