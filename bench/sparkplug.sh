#!/usr/bin/env bash
# The Sparkplug B edge node's benchmark (issue 16), not run in CI.
#
#  1. `drivebus serve` with 1000 simulated drives on 32 virtual buses (bench/lib/plant.sh)
#     as Sparkplug edge node "load" on Mosquitto, pinned to core $SERVER_CORE; a Python host
#     (bench/sparkplug_load.py, paho-mqtt + pysparkplug) on core $CLIENT_CORE runs every drive
#     by DCMD, the setpoint switching between 20 and 50 Hz every 6 s, and counts DDATA for
#     $SECS s: DDATA/s, and the gateway's CPU over the same time (/proc/PID/stat).
#  2. One hour of stored changes at the measured rate, put in the store's queue
#     (crates/gateway/examples/sparkplug_fill.rs), drained to a primary host that comes
#     online at the pace $DRAIN_RATE (store_forward_rate, default 10 000/s): the time from
#     NBIRTH to the last historical DDATA, all of them received.
#
# SECS=30 bench/sparkplug.sh     RATE=N skips step 1 (an hour is N x 3600 messages);
#                                HOUR_MESSAGES=N gives the hour's count itself
set -euo pipefail
cd "$(dirname "$0")/.."
. bench/lib/plant.sh
SECS=${SECS:-30}
SERVER_CORE=${SERVER_CORE:-0}
CLIENT_CORE=${CLIENT_CORE:-1}
# The drain's pace (store_forward_rate): what the Python host takes without the broker dropping.
DRAIN_RATE=${DRAIN_RATE:-10000}

cargo build --release -q -p drivebus
cargo build --release -q -p drivebus-gateway --example sparkplug_fill
BIN=target/release/drivebus
FILL=target/release/examples/sparkplug_fill
MOSQUITTO=$(command -v mosquitto || echo /usr/sbin/mosquitto)

. bench/lib/run.sh


BP=$(free_port)
printf 'listener %s 127.0.0.1\nallow_anonymous true\npersistence false\nmax_queued_messages 1000000\n' "$BP" >"$TMP/mosquitto.conf"
taskset -c "$CLIENT_CORE" "$MOSQUITTO" -c "$TMP/mosquitto.conf" >"$TMP/mosquitto.log" 2>&1 &
PIDS+=("$!")
wait_port "$BP"

CFG="$TMP/plant.toml"
# The queue's limit above an hour of data, so that none of it is dropped.
write_plant "$CFG" load "$(printf '[sparkplug]\nurls = ["mqtt://127.0.0.1:%s"]\ncommands = true\nstore_forward_max = 100000000\nstore_forward_rate = %s\n' \
  "$BP" "$DRAIN_RATE")"

if [ -z "${RATE:-}" ]; then
echo "== 1000 drives on 32 virtual buses, Sparkplug edge node on core $SERVER_CORE, ${SECS} s of DDATA"
taskset -c "$SERVER_CORE" "$BIN" serve --config "$CFG" --db "$TMP/live.db" --http "127.0.0.1:$(free_port)" \
  --modbus "127.0.0.1:$(free_port)" >"$TMP/gw.log" 2>&1 &
GW=$!; PIDS+=("$GW")
taskset -c "$CLIENT_CORE" python3 bench/sparkplug_load.py "127.0.0.1:$BP" rate "$SECS" load 1000 >"$TMP/rate.json" &
LOAD=$!
# The CPU over the counted seconds: the load script waits for the births and 3 s of ramp first.
commands() { grep -c 'command .* by sparkplug' "$TMP/gw.log" 2>/dev/null || true; }
until [ "$(commands)" -ge 2000 ]; do sleep 0.2; done
sleep 3
T0=$(cpu_ticks "$GW"); S0=$(date +%s.%N)
wait "$LOAD"
T1=$(cpu_ticks "$GW"); S1=$(date +%s.%N)
HZ=$(getconf CLK_TCK)
CPU=$(python3 -c "print(round(100 * ($T1 - $T0) / $HZ / ($S1 - $S0), 1))")
RATE=$(python3 -c "import json; print(json.load(open('$TMP/rate.json'))['ddata_per_s'])")
echo "DDATA: $(cat "$TMP/rate.json"); gateway CPU ${CPU}% of one core (the simulated drives included)"
stop "$GW"
fi

HOUR=${HOUR_MESSAGES:-$((RATE * 3600))}
echo "== draining one hour of stored changes: $HOUR DDATA messages, at most $DRAIN_RATE/s"
"$FILL" "$TMP/drain.db" drivebus/load "$HOUR" 1000
taskset -c "$SERVER_CORE" "$BIN" serve --config "$CFG" --db "$TMP/drain.db" --sparkplug-primary bench-host \
  --http "127.0.0.1:$(free_port)" --modbus "127.0.0.1:$(free_port)" >"$TMP/gw2.log" 2>&1 &
GW=$!; PIDS+=("$GW")
sleep 2
taskset -c "$CLIENT_CORE" python3 bench/sparkplug_load.py "127.0.0.1:$BP" drain bench-host load "$HOUR"
stop "$GW"
