#!/usr/bin/env bash
# Runs every fuzz target from its seed corpus (fuzz/corpus/<target>, from
# fuzz/seeds/make-corpus.py) and prints each one's execution count. Needs cargo-fuzz and a
# nightly toolchain (`rustup toolchain install nightly`; `.ci/install-witnesses.sh` installs
# cargo-fuzz). Two targets run at a time (one per core); JOBS changes that.
#
#   fuzz/run-all.sh                    # 10 minutes each
#   fuzz/run-all.sh 30                 # 30 seconds each (what CI runs)
#   fuzz/run-all.sh 60 b800 config     # one minute, two targets
#   fuzz/run-all.sh --runs 100000000   # until 10^8 executions each (a long run)
#
# A crash stops the run: the input is in fuzz/artifacts/<target>/, the log in fuzz/logs/.
set -euo pipefail
cd "$(dirname "$0")"
limit=(-max_total_time=600)
what="600 s"
if [ "${1:-}" = "--runs" ]; then
  limit=(-runs="${2:?--runs N}")
  what="$2 executions"
  shift 2
elif [ $# -gt 0 ]; then
  limit=(-max_total_time="$1")
  what="$1 s"
  shift
fi
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(modbus_rtu modbus_ascii toshiba_ascii toshiba_binary danfoss_fc b800 modbus_tcp config)
toolchain=${FUZZ_TOOLCHAIN:-+nightly}
# -O (release) by default; CI builds --dev, which compiles the gateway in half the time.
build=${FUZZ_BUILD:--O}
jobs=${JOBS:-2}
mkdir -p logs
[ -d corpus ] || python3 seeds/make-corpus.py

# One build for every target, then the runs.
cargo $toolchain fuzz build $build -a -s none >logs/build.log 2>&1 || { cat logs/build.log >&2; exit 1; }

run() {
  local t=$1
  mkdir -p "corpus/$t" "runs/$t"
  # New inputs go to fuzz/runs/ (not committed); the seed corpus stays as it is.
  if cargo $toolchain fuzz run $build -a -s none "$t" "runs/$t" "corpus/$t" -- "${limit[@]}" -print_final_stats=1 \
    >"logs/$t.log" 2>&1; then
    local runs speed
    runs=$(grep -E '^stat::number_of_executed_units' "logs/$t.log" | awk '{print $2}')
    speed=$(grep -E '^stat::average_exec_per_sec' "logs/$t.log" | awk '{print $2}')
    echo "$t: $runs executions ($what asked, $speed/s), no crash"
  else
    echo "$t: FAILED, see fuzz/logs/$t.log and fuzz/artifacts/$t" >&2
    tail -n 30 "logs/$t.log" >&2
    return 1
  fi
}

failed=0
pids=()
for t in "${targets[@]}"; do
  run "$t" &
  pids+=($!)
  if [ ${#pids[@]} -ge "$jobs" ]; then
    wait "${pids[0]}" || failed=1
    pids=("${pids[@]:1}")
  fi
done
for p in "${pids[@]}"; do wait "$p" || failed=1; done
exit $failed
