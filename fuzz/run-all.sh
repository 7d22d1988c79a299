#!/usr/bin/env bash
# Runs every deframer fuzz target for SECONDS (default 600) one after the other and prints the
# execution count of each. Needs cargo-fuzz (`cargo install cargo-fuzz`); on a stable toolchain
# RUSTC_BOOTSTRAP=1 lets it pass the sanitizer flags libFuzzer needs.
#
#   fuzz/run-all.sh            # 10 minutes each
#   fuzz/run-all.sh 60 b800    # one minute, one target
set -euo pipefail
cd "$(dirname "$0")"
secs=${1:-600}
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(modbus_rtu modbus_ascii toshiba_ascii toshiba_binary danfoss_fc b800)
export RUSTC_BOOTSTRAP=1
mkdir -p logs
for t in "${targets[@]}"; do
  cargo fuzz build -O -a -s none "$t" >/dev/null 2>&1 || cargo fuzz build -O -a -s none "$t"
  mkdir -p "corpus/$t"
  cargo fuzz run -O -a -s none "$t" "corpus/$t" -- -max_total_time="$secs" -print_final_stats=1 >"logs/$t.log" 2>&1 || {
    echo "$t: FAILED, see fuzz/logs/$t.log and fuzz/artifacts/$t" >&2
    exit 1
  }
  runs=$(grep -E '^stat::number_of_executed_units' "logs/$t.log" | awk '{print $2}')
  speed=$(grep -E '^stat::average_exec_per_sec' "logs/$t.log" | awk '{print $2}')
  echo "$t: $runs executions in ${secs}s ($speed/s), no crash"
done
