#!/usr/bin/env bash
# drivebus sniff on a 115200-baud virtual line at full load: a master reads 2 registers at
# 2100H from a simulated drive (response time 200 us) in a tight loop for SECONDS while
# `drivebus sniff --json` listens on the simulator's tap. The master is pymodbus (the default)
# or, with MASTER=drivebus, drivebus's blocking bus (crates/link/examples/pty_read.rs), which
# loads the line more. Prints the frames the line carried
# (the simulator's byte counts / frame sizes: 8-byte requests, 9-byte replies), the valid
# frames sniff saw, and sniff's CPU (user + system) as a share of one core.
#
#   bench/sniff.sh [SECONDS]                  (default 60)
#   MASTER=drivebus bench/sniff.sh [SECONDS]
#
# Needs python3 with pymodbus (installed by .ci/install-witnesses.sh) and curl.
set -euo pipefail
cd "$(dirname "$0")/.."
SECS=${1:-60}
WORK=$(mktemp -d)
SIM_PID=
SNIFF_PID=
cleanup() {
    for p in $SNIFF_PID $SIM_PID; do kill "$p" 2>/dev/null || true; wait "$p" 2>/dev/null || true; done
    rm -rf "$WORK"
}
trap cleanup EXIT

echo "building (release) ..." >&2
cargo build --release -q -p drivebus
BIN=${CARGO_TARGET_DIR:-target}/release/drivebus
MASTER=${MASTER:-pymodbus}
if [ "$MASTER" = drivebus ]; then
    cargo build --release -q -p drivebus-link --example pty_read
fi

"$BIN" simulate --drive generic@1:modbus-rtu --baud 115200 --serial 8N1 --response-us 200 \
    --pty "$WORK/bus" --tap "$WORK/tap" --control 127.0.0.1:0 >"$WORK/sim.log" 2>&1 &
SIM_PID=$!
until grep -q "listening on" "$WORK/sim.log" 2>/dev/null; do sleep 0.1; done
CONTROL=$(sed -n 's|^control http://\(.*\)/drives$|\1|p' "$WORK/sim.log")

# sniff: output to a file, CPU from /usr/bin/time; stopped with SIGINT once the load is over.
/usr/bin/time -f "%e %U %S" -o "$WORK/time" "$BIN" sniff --port "$WORK/tap" --baud 115200 --serial 8N1 \
    --json >"$WORK/sniff.json" 2>"$WORK/sniff.err" &
SNIFF_PID=$!
until grep -q "listening on" "$WORK/sniff.err" 2>/dev/null; do sleep 0.1; done

if [ "$MASTER" = drivebus ]; then
    "${CARGO_TARGET_DIR:-target}/release/examples/pty_read" "$WORK/bus" "$SECS" 0
else
    python3 bench/clients/pymodbus_client.py "$WORK/bus" "$SECS"
fi
STATS=$(curl -s "http://$CONTROL/stats")
# Let sniff read the last reply off the tap, then stop it as Ctrl-C does.
LINES=0
for _ in $(seq 50); do
    N=$(wc -l <"$WORK/sniff.json")
    [ "$N" = "$LINES" ] && [ "$N" != 0 ] && break
    LINES=$N
    sleep 0.2
done
# SIGINT to sniff itself (/usr/bin/time, its parent, ignores it).
kill -INT "$(pgrep -P "$SNIFF_PID")"
wait "$SNIFF_PID" || true
SNIFF_PID=

cp "$WORK/sniff.json" "${KEEP:-/dev/null}" 2>/dev/null || true
python3 - "$STATS" "$WORK/sniff.json" "$WORK/time" "$SECS" <<'PY'
import json, sys
stats = json.loads(sys.argv[1])
frames_in = stats["master_bytes"] // 8 + stats["device_bytes"] // 9
valid = invalid = 0
with open(sys.argv[2]) as f:
    for line in f:
        o = json.loads(line)
        if o.get("event"):
            continue
        if o["valid"]:
            valid += 1
        else:
            invalid += 1
wall, user, sys_ = (float(x) for x in open(sys.argv[3]).read().split()[-3:])
print(f"line: {stats['master_bytes']} master bytes, {stats['device_bytes']} drive bytes = {frames_in} frames; "
      f"utilization {stats['utilization'] * 100:.1f} % at {stats['baud']} {stats['serial']}")
print(f"sniff: {valid} valid frames, {invalid} invalid; frames out == frames in: {valid == frames_in}")
print(f"sniff CPU: {user:.2f} s user + {sys_:.2f} s system over {wall:.1f} s = {(user + sys_) / wall * 100:.2f} % of a core")
PY
