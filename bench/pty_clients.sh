#!/usr/bin/env bash
# Modbus RTU clients over a raw pty, same simulator, same read, same run: drivebus (its
# blocking bus, and as drivebus-async its bus owner task; crates/link/examples/pty_read.rs),
# pymodbus, libmodbus and tokio-modbus each read 2 registers at 2100H from drive 1 in a tight
# loop for SECONDS; prints reads/s and latency. With two cores or more the simulator is pinned
# to core 0 and every client to core 1 (PIN=0 turns this off), so all of them see the same
# placement and the scheduler's moves do not decide the result.
#
#   bench/pty_clients.sh [SECONDS]        (default 5; ROUNDS=3 repeats the set)
#   SERVER=floor bench/pty_clients.sh     the same clients, and a bare C client
#                                         (bench/clients/pty_floor_client.c), against a C
#                                         program that only answers (bench/clients/
#                                         pty_floor_server.c): what the pty itself allows
#
# The simulator runs with --no-pacing --response-us 0 (a pty has no baud rate: bytes take no
# wire time) so the clients are measured, not the virtual line; drivebus runs with --gap 0
# (no RS-485 line behind a pty, so no t3.5 silence to keep). Needs gcc, python3; installs
# libmodbus-dev (apt) and pymodbus (pip) when missing.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
SECS=${1:-5}
ROUNDS=${ROUNDS:-1}
WORK=$(mktemp -d)
SIM_PID=
cleanup() {
    if [ -n "$SIM_PID" ]; then kill "$SIM_PID" 2>/dev/null || true; wait "$SIM_PID" 2>/dev/null || true; fi
    rm -rf "$WORK"
}
trap cleanup EXIT

echo "building (release) ..." >&2
cargo build --release -q -p drivebus
cargo build --release -q -p drivebus-link --example pty_read
CARGO_TARGET_DIR=$ROOT/target cargo build --release -q --manifest-path bench/clients/tokio-modbus-client/Cargo.toml
if ! pkg-config --exists libmodbus 2>/dev/null; then
    echo "installing libmodbus-dev ..." >&2
    (apt-get install -y -q libmodbus-dev >/dev/null 2>&1) || (apt-get update -q >/dev/null && apt-get install -y -q libmodbus-dev >/dev/null)
fi
gcc -O2 -o "$WORK/libmodbus_client" bench/clients/libmodbus_client.c $(pkg-config --cflags --libs libmodbus)
gcc -O2 -o "$WORK/pty_floor_server" bench/clients/pty_floor_server.c
gcc -O2 -o "$WORK/pty_floor_client" bench/clients/pty_floor_client.c
if ! python3 -c "import pymodbus, serial" 2>/dev/null; then
    echo "installing pymodbus ..." >&2
    python3 -m pip install -q pymodbus pyserial 2>/dev/null || python3 -m pip install -q --break-system-packages pymodbus pyserial
fi

SIM_CPU=()
CLIENT_CPU=()
if [ "${PIN:-1}" = 1 ] && [ "$(nproc)" -ge 2 ] && command -v taskset >/dev/null; then
    SIM_CPU=(taskset -c 0)
    CLIENT_CPU=(taskset -c 1)
fi

PTY=$WORK/pty
SERVER=${SERVER:-simulator}
case "$SERVER" in
    simulator)
        "${SIM_CPU[@]}" "$ROOT/target/release/drivebus" simulate --drive generic@1:modbus-rtu --baud 115200 --serial 8N1 \
            --no-pacing --response-us 0 --pty "$PTY" >"$WORK/sim.log" 2>&1 &
        ;;
    floor) "${SIM_CPU[@]}" "$WORK/pty_floor_server" "$PTY" >"$WORK/sim.log" 2>&1 & ;;
    *) echo "SERVER must be simulator or floor, not $SERVER" >&2; exit 3 ;;
esac
SIM_PID=$!
for _ in $(seq 50); do grep -q "listening on" "$WORK/sim.log" && break; sleep 0.1; done
grep -q "listening on" "$WORK/sim.log" || { echo "the $SERVER did not start: $(cat "$WORK/sim.log")" >&2; exit 2; }

RESULTS=$WORK/results
for round in $(seq "$ROUNDS"); do
    echo "round $round/$ROUNDS: $SECS s per client ..." >&2
    "${CLIENT_CPU[@]}" "$ROOT/target/release/examples/pty_read" "$PTY" "$SECS" 0 blocking >>"$RESULTS"
    "${CLIENT_CPU[@]}" "$ROOT/target/release/examples/pty_read" "$PTY" "$SECS" 0 async >>"$RESULTS"
    "${CLIENT_CPU[@]}" python3 bench/clients/pymodbus_client.py "$PTY" "$SECS" >>"$RESULTS"
    "${CLIENT_CPU[@]}" "$WORK/libmodbus_client" "$PTY" "$SECS" >>"$RESULTS"
    "${CLIENT_CPU[@]}" "$ROOT/target/release/tokio-modbus-client" "$PTY" "$SECS" >>"$RESULTS"
    if [ "$SERVER" = floor ]; then "${CLIENT_CPU[@]}" "$WORK/pty_floor_client" "$PTY" "$SECS" >>"$RESULTS"; fi
done

PLACEMENT="unpinned"
[ ${#SIM_CPU[@]} -gt 0 ] && PLACEMENT="simulator on core 0, clients on core 1"
SERVED="simulator --no-pacing --response-us 0"
[ "$SERVER" = floor ] && SERVED="answered by bench/clients/pty_floor_server.c"
python3 - "$RESULTS" "$SECS" "$ROUNDS" "$PLACEMENT" "$SERVED" <<'PY'
import sys, statistics
rows = {}
for line in open(sys.argv[1]):
    name, *kv = line.split()
    rows.setdefault(name, []).append({k: float(v) for k, v in (x.split("=") for x in kv)})
print(f"Modbus RTU over a pty, read 2 registers at 2100H from drive 1, {sys.argv[2]} s per client, "
      f"{sys.argv[3]} round(s), median of rounds; {sys.argv[5]}; {sys.argv[4]}")
print()
print("| client | reads/s | p50 latency µs | p99 latency µs | errors |")
print("|---|---:|---:|---:|---:|")
med = {}
for name, rs in rows.items():
    m = {k: statistics.median(r[k] for r in rs) for k in rs[0]}
    med[name] = m
    print(f"| {name} | {m['reads_per_s']:.0f} | {m['p50_us']:.0f} | {m['p99_us']:.0f} | {m['errors']:.0f} |")
others = {k: v for k, v in med.items() if not k.startswith("drivebus") and k != "bare-c"}
if "drivebus" in med and others:
    best = max(others, key=lambda k: others[k]["reads_per_s"])
    ratio = med["drivebus"]["reads_per_s"] / max(others[best]["reads_per_s"], 1)
    print()
    print(f"drivebus / best other ({best}): {ratio:.2f}x (target >= 1.20x)")
PY
