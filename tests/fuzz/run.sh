#!/usr/bin/env bash
# Fuzzes every libFuzzer target of tests/fuzz for SECONDS each, $COMPOSE_FUZZ_JOBS (default: the
# number of cores) targets at a time (each may use up to 2 GB and its sanitizers' overhead); the
# report is printed when all have finished. Needs bash 4.3 or later (wait -n).
#
#   tests/fuzz/run.sh SECONDS [TARGET...]
#
# The targets are found in $COMPOSE_FUZZ_BUILD_DIR (default build-sanitize; configure it with
# CXX=clang++ cmake -DCOMPOSE_FUZZ=ON, as setup.sh test does). Each target starts from its seed
# corpus (tests/fuzz/corpus/<name>) and its regressions (tests/fuzz/regressions/<name>); what it
# finds new goes to a working corpus in $COMPOSE_FUZZ_WORK (default <build>/fuzz-work/<name>), so
# that the repository's corpus stays small. A crash, a leak, a timeout (10 s for one input) or an
# input that needs more than 2 GB stops the target; its input is saved as
# <work>/<name>/crash-* (or leak-, timeout-, oom-): fix the bug, then copy the file to
# tests/fuzz/regressions/<name>/ so that ctest replays it.
#
# Prints one line per target: executions, executions per second, coverage (edges) and features
# at the end, and the corpus size; exits 1 if any target failed.
set -uo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/../.."

if [ $# -lt 1 ] || ! [[ $1 =~ ^[0-9]+$ ]]; then
  echo "usage: $0 SECONDS [TARGET...]" >&2
  exit 2
fi
seconds=$1
shift
build=${COMPOSE_FUZZ_BUILD_DIR:-build-sanitize}
fuzzdir=$build/tests/fuzz
work=${COMPOSE_FUZZ_WORK:-$build/fuzz-work}
if [ $# -gt 0 ]; then
  targets=("$@")
else
  targets=()
  for exe in "$fuzzdir"/fuzz_*; do
    [ -x "$exe" ] && [ -f "$exe" ] && targets+=("$(basename "$exe" | sed 's/^fuzz_//')")
  done
fi
if [ ${#targets[@]} -eq 0 ]; then
  echo "fuzz: no targets in $fuzzdir (configure with CXX=clang++ -DCOMPOSE_FUZZ=ON and build)" >&2
  exit 2
fi

jobs=${COMPOSE_FUZZ_JOBS:-$(nproc)}
[[ $jobs =~ ^[1-9][0-9]*$ ]] || jobs=1

# Fuzzes one target; its report line goes to <work>/<target>/result, "ok" or the failure last.
fuzz_one() {
  local t=$1 exe=$fuzzdir/fuzz_$1
  mkdir -p "$work/$t/corpus"
  local corpus=$work/$t/corpus log=$work/$t/log.txt result=$work/$t/result
  rm -f "$result" "$log"
  if [ ! -x "$exe" ]; then
    printf '%-12s %12s %10s %8s %8s %8s  %s\n' "$t" - - - - - "FAILED: no target $exe" >"$result"
    return
  fi
  # The working corpus first: libFuzzer adds what it finds to the first folder only.
  # intercept_tls_get_addr=0 whatever the caller sets: see setup.sh (LeakSanitizer's tracer crash).
  ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1}:intercept_tls_get_addr=0 \
    LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$PWD/tests/lsan.supp} \
    "$exe" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 \
    -artifact_prefix="$work/$t/" "$corpus" "tests/fuzz/corpus/$t" "tests/fuzz/regressions/$t" \
    >"$log" 2>&1
  local status=$?
  local runs speed last cov ft files outcome
  runs=$(grep -Eo 'stat::number_of_executed_units: *[0-9]+' "$log" | grep -Eo '[0-9]+$' | tail -n 1)
  speed=$(grep -Eo 'stat::average_exec_per_sec: *[0-9]+' "$log" | grep -Eo '[0-9]+$' | tail -n 1)
  last=$(grep -E '^#[0-9]+' "$log" | grep -E 'cov: ' | tail -n 1)
  cov=$(sed -nE 's/.*cov: ([0-9]+).*/\1/p' <<<"$last")
  ft=$(sed -nE 's/.*ft: ([0-9]+).*/\1/p' <<<"$last")
  files=$(find "$corpus" -type f | wc -l)
  if [ $status -eq 0 ]; then
    outcome=ok
  else
    outcome="FAILED (status $status): $(grep -Eo '(crash|leak|timeout|oom|slow-unit)-[0-9a-f]+' \
      "$log" | head -n 1) in $work/$t; log $log"
  fi
  printf '%-12s %12s %10s %8s %8s %8s  %s\n' "$t" "${runs:-?}" "${speed:-?}" "${cov:-?}" \
    "${ft:-?}" "$files" "$outcome" >"$result"
}

printf '%-12s %12s %10s %8s %8s %8s  %s\n' target executions exec/s cov ft corpus result
running=0
for t in "${targets[@]}"; do
  if [ $running -ge "$jobs" ]; then
    wait -n
    running=$((running - 1))
  fi
  fuzz_one "$t" &
  running=$((running + 1))
done
wait

failed=()
for t in "${targets[@]}"; do
  if [ -f "$work/$t/result" ]; then
    cat "$work/$t/result"
    grep -q '  ok$' "$work/$t/result" || failed+=("$t")
  else
    printf '%-12s  FAILED: no result\n' "$t"
    failed+=("$t")
  fi
done

if [ ${#failed[@]} -gt 0 ]; then
  echo "fuzz: ${#failed[@]} target(s) failed: ${failed[*]}" >&2
  for t in "${failed[@]}"; do
    [ -f "$work/$t/log.txt" ] && grep -E -A 12 '^==[0-9]+==ERROR|fuzz check failed|deadly signal' \
      "$work/$t/log.txt" | head -n 40 >&2
  done
  exit 1
fi
