#!/usr/bin/env bash
# The gateway's load benchmark (issue 5), not run in CI.
#
#  1. `drivebus serve --demo` pinned to core 0, the load generator (crates/gateway/examples/
#     loadgen.rs, one thread) pinned to core 1: 128 Modbus TCP clients reading 10 input
#     registers in a loop, alone and then together with 64 keep-alive HTTP clients
#     (GET $HTTP_PATH), $SECS s each: requests/s and latency percentiles; and the 128 clients
#     at $RATE requests/s together (default 50 000), for the latency below saturation.
#  2. The same 128 Modbus clients against libmodbus' TCP server (bench/libmodbus_server.c,
#     compiled here), pymodbus' TCP server (bench/pymodbus_server.py) and a server that does
#     the least a server can (bench/modbus_floor_server.c: one epoll loop, a recv and a send
#     per request), same pinning, same run.
#  3. 10 000 concurrent connections to the gateway: all connected, then each reads once.
#  4. RSS of `drivebus serve` with 1000 simulated drives on 32 virtual buses, after 10 s.
#
# The load generator's clients all come from 127.0.0.1: the gateway runs the demo plant with
# `[limits] per_address` raised to $PER_ADDRESS (the default, 64, would refuse all but 64 of
# them; a plant's clients come from many addresses).
#
# SECS=10 HTTP_PATH=/api/drives bench/gateway_load.sh
set -euo pipefail
cd "$(dirname "$0")/.."
. bench/lib/plant.sh
SECS=${SECS:-10}
HTTP_PATH=${HTTP_PATH:-/api/drives}
CONNS=${CONNS:-10000}
SERVER_CORE=${SERVER_CORE:-0}
CLIENT_CORE=${CLIENT_CORE:-1}
# The rate of the unsaturated run (requests/s from all 128 clients together).
RATE=${RATE:-50000}
PER_ADDRESS=${PER_ADDRESS:-100000}

cargo build --release -q -p drivebus
cargo build --release -q -p drivebus-gateway --example loadgen
BIN=target/release/drivebus
LOADGEN=target/release/examples/loadgen
ulimit -n "$(ulimit -Hn)"

. bench/lib/run.sh

# The demo plant with the per-address connection limit raised (see above).
DEMO="$TMP/demo.toml"
sed "0,/^name = \"demo\"$/s//name = \"demo\"\n[limits]\nper_address = $PER_ADDRESS/" \
  crates/gateway/src/demo.toml >"$DEMO"

load() { taskset -c "$CLIENT_CORE" "$LOADGEN" load --secs "$SECS" "$@"; }
# serve_other NAME PROGRAM ARGS...: starts a server on the server core with a free port as its
# last argument, waits until it listens, and sets SRV_PORT and SRV_PID.
serve_other() {
  local name=$1; shift
  SRV_PORT=$(free_port)
  taskset -c "$SERVER_CORE" "$@" "$SRV_PORT" >"$TMP/$name.log" 2>&1 &
  SRV_PID=$!; PIDS+=("$SRV_PID")
  wait_port "$SRV_PORT"
}

echo "== gateway: the demo plant (per_address $PER_ADDRESS) on core $SERVER_CORE, load generator on core $CLIENT_CORE, ${SECS} s per run"
MP=$(free_port); HP=$(free_port)
taskset -c "$SERVER_CORE" "$BIN" serve --config "$DEMO" --no-store --modbus "127.0.0.1:$MP" --http "127.0.0.1:$HP" >"$TMP/gw.log" 2>&1 &
GW=$!; PIDS+=("$GW")
wait_port "$MP"; wait_port "$HP"; sleep 2
load --modbus "127.0.0.1:$MP" --clients 128 --units 1-10
echo "-- the same 128 clients at $RATE requests/s together (not saturated)"
load --modbus "127.0.0.1:$MP" --clients 128 --units 1-10 --rate "$RATE"
load --modbus "127.0.0.1:$MP" --clients 128 --units 1-10 --http "127.0.0.1:$HP" --http-clients 64 --path "$HTTP_PATH"
stop "$GW"

echo "== libmodbus $(pkg-config --modversion libmodbus 2>/dev/null || echo '?') TCP server (select loop) on core $SERVER_CORE"
if ! pkg-config --exists libmodbus; then
  echo "libmodbus-dev is missing: apt-get install libmodbus-dev" >&2
else
  cc -O2 -o "$TMP/libmodbus_server" bench/libmodbus_server.c $(pkg-config --cflags --libs libmodbus)
  serve_other libmodbus "$TMP/libmodbus_server"
  load --modbus "127.0.0.1:$SRV_PORT" --clients 128 --units 1
  echo "-- the same 128 clients at $RATE requests/s together (not saturated)"
  load --modbus "127.0.0.1:$SRV_PORT" --clients 128 --units 1 --rate "$RATE"
  stop "$SRV_PID"
fi

echo "== the least a server can do (bench/modbus_floor_server.c, epoll) on core $SERVER_CORE"
cc -O2 -o "$TMP/modbus_floor_server" bench/modbus_floor_server.c
serve_other floor "$TMP/modbus_floor_server"
load --modbus "127.0.0.1:$SRV_PORT" --clients 128 --units 1
stop "$SRV_PID"

echo "== pymodbus $(python3 -c 'import pymodbus; print(pymodbus.__version__)' 2>/dev/null || echo '?') TCP server on core $SERVER_CORE"
if ! python3 -c 'import pymodbus' 2>/dev/null; then
  echo "pymodbus is missing: python3 -m pip install pymodbus" >&2
else
  serve_other pymodbus python3 bench/pymodbus_server.py
  load --modbus "127.0.0.1:$SRV_PORT" --clients 128 --units 1
  stop "$SRV_PID"
fi

echo "== $CONNS concurrent connections to the gateway"
MP=$(free_port); HP=$(free_port)
taskset -c "$SERVER_CORE" "$BIN" serve --config "$DEMO" --no-store --modbus "127.0.0.1:$MP" --http "127.0.0.1:$HP" >"$TMP/gw2.log" 2>&1 &
GW=$!; PIDS+=("$GW")
wait_port "$MP"; sleep 1
taskset -c "$CLIENT_CORE" "$LOADGEN" conns --modbus "127.0.0.1:$MP" --n "$CONNS"
echo "gateway RSS after the connections closed: $(awk '/VmRSS/ {print $2, $3}' /proc/$GW/status)"
stop "$GW"

echo "== RSS with 1000 simulated drives on 32 virtual buses (115200 baud, poll 500 ms)"
CFG="$TMP/big.toml"
write_plant "$CFG"
MP=$(free_port); HP=$(free_port)
taskset -c "$SERVER_CORE" "$BIN" serve --config "$CFG" --no-store --modbus "127.0.0.1:$MP" --http "127.0.0.1:$HP" >"$TMP/gw3.log" 2>&1 &
GW=$!; PIDS+=("$GW")
wait_port "$MP"
sleep 10
echo "drivebus serve: $(head -n 1 "$TMP/gw3.log"); VmRSS $(awk '/VmRSS/ {print $2, $3}' /proc/$GW/status) after 10 s"
ONLINE=$(curl -s "http://127.0.0.1:$HP/api/drives" | python3 -c 'import json,sys; d=json.load(sys.stdin); print(sum(1 for x in d if x["online"]), "of", len(d))' 2>/dev/null || echo "?")
echo "drives online: $ONLINE"
stop "$GW"
