#!/usr/bin/env bash
# Parameter-read floods against polling (issue 13, defect 1), not run in CI.
#
# `drivebus serve` on the demo's plant, while 4 Modbus TCP clients read fan-1's whole parameter
# window (unit 3, 124 registers from 1000) and 16 HTTP clients read
# /api/drives/fan-1/params/P0.02, all from loopback and without pause: conveyor-1's data age
# (polled every 250 ms on the same 38 400 baud bus), sampled every 100 ms for $SECS s.
#
#  before: on_demand_share = 1.0, param_cache_ms = 0 and queues of a million (parameter reads
#          ahead of polls, every read on the bus, no bound: how the gateway behaved before)
#  after:  the defaults (on_demand_share = 0.5, param_cache_ms = 200)
#  after, no reuse: the defaults but param_cache_ms = 0 (every read on the bus)
#
# Measured (debug build, 2 shared cores, SECS=20; conveyor-1's age_ms):
#  before:          median 10 040, p95 19 090, max 20 002 ms; 4 windows, 1 692 parameter reads
#  after:           median 126, p95 238, max 276 ms; 84 windows, 61 761 parameter reads, none busy
#  after, no reuse: median 125, p95 241, max 262 ms; 1 034 parameter reads (69 170 busy: 16
#                   readers from one address over its 8 waiting), windows all busy (the same
#                   address's HTTP readers hold its 8 places)
#
# SECS=20 bench/flood.sh
set -euo pipefail
cd "$(dirname "$0")/.."
SECS=${SECS:-20}
cargo build -q -p drivebus
BIN=${BIN:-${CARGO_TARGET_DIR:-target}/debug/drivebus}
. bench/lib/run.sh

flood() {
  local label=$1 extra=$2
  python3 - "$TMP/plant.toml" "$extra" <<'PY'
import sys
text = open("crates/gateway/src/demo.toml").read()
extra = sys.argv[2].replace("\\n", "\n")
text = text.replace('name = "line-generic"\n', 'name = "line-generic"\n' + extra + "\n", 1)
open(sys.argv[1], "w").write(text)
PY
  local mp hp
  mp=$(free_port); hp=$(free_port)
  "$BIN" serve --config "$TMP/plant.toml" --no-store --no-opcua --modbus "127.0.0.1:$mp" --http "127.0.0.1:$hp" >"$TMP/gw.log" 2>&1 &
  local gw=$!; PIDS+=("$gw")
  wait_port "$mp"; wait_port "$hp"; sleep 2
  python3 - "$mp" "$hp" "$SECS" "$label" <<'PY'
import json, socket, statistics, struct, sys, threading, time, http.client
mp, hp, secs, label = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
stop = time.time() + secs
counts = {"window": 0, "window busy": 0, "param": 0, "param busy": 0}
lock = threading.Lock()
def count(k):
    with lock:
        counts[k] += 1
def window():
    s = socket.create_connection(("127.0.0.1", mp))
    tid = 0
    while time.time() < stop:
        tid = (tid + 1) & 0xFFFF
        s.sendall(struct.pack(">HHHBBHH", tid, 0, 6, 3, 3, 1000, 124))
        h = b""
        while len(h) < 7:
            h += s.recv(7 - len(h))
        n = struct.unpack(">H", h[4:6])[0] - 1
        pdu = b""
        while len(pdu) < n:
            pdu += s.recv(n - len(pdu))
        count("window busy" if pdu[:2] == b"\x83\x06" else "window")
def param():
    c = http.client.HTTPConnection("127.0.0.1", hp)
    while time.time() < stop:
        c.request("GET", "/api/drives/fan-1/params/P0.02")
        r = c.getresponse(); r.read()
        count("param busy" if r.status == 429 else "param")
threads = [threading.Thread(target=window, daemon=True) for _ in range(4)]
threads += [threading.Thread(target=param, daemon=True) for _ in range(16)]
for t in threads:
    t.start()
ages = []
c = http.client.HTTPConnection("127.0.0.1", hp)
while time.time() < stop:
    c.request("GET", "/api/drives/conveyor-1")
    ages.append(json.loads(c.getresponse().read())["age_ms"] or 0)
    time.sleep(0.1)
ages.sort()
print(f"{label}: conveyor-1 age_ms median {statistics.median(ages):.0f}, p95 {ages[int(len(ages) * 0.95)]}, max {ages[-1]} "
      f"({len(ages)} samples); in {secs:.0f} s: {counts['window']} windows ({counts['window busy']} busy), "
      f"{counts['param']} parameter reads ({counts['param busy']} busy)")
PY
  stop "$gw"
}

flood "before (reads ahead of polls, no reuse, no bound)" \
  'on_demand_share = 1.0\nparam_cache_ms = 0\non_demand_queue = 1000000\non_demand_per_client = 1000000'
flood "after (defaults)" ''
flood "after, no reuse (param_cache_ms = 0)" 'param_cache_ms = 0'
