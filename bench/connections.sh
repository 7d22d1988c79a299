#!/usr/bin/env bash
# Connection exhaustion (issue 13, defect 2), not run in CI.
#
# `drivebus serve --demo` under a descriptor limit of 20 000 (this machine's hard limit), then
# 20 000 idle connections to its HTTP listener from 127.0.0.2 (two client processes of 10 000:
# a process may hold no more), then, while they are held, from 127.0.0.3: an HTTP request and a
# Modbus TCP read, each timed (10 s at most). And a half-sent HTTP header from 127.0.0.3: how
# long until the gateway closes it.
#
#  before: [limits] per_address = 1000000, reserve_fds = 0, idle_timeout_s = 0,
#          header_timeout_ms = 600000 (no per-address limit, no reserve, no timeouts to speak of)
#  after:  the defaults (per_address = 64, reserve_fds = 256, header 5 s, idle 300 s)
#
# Measured (debug build, 2 shared cores):
#  before: all 20 000 held (19 998 descriptors open); from 127.0.0.3 the HTTP GET, the Modbus
#          read and the half-sent header all reset at once: the gateway serves nobody
#  after:  the gateway holds 13 descriptors; from 127.0.0.3 the HTTP GET is answered 200 in
#          1 ms, the Modbus read in 0 ms; the half-sent header closed after 5 001 ms; 20 000
#          refusals in 2 log lines
#
# bench/connections.sh
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build -q -p drivebus
BIN=${BIN:-${CARGO_TARGET_DIR:-target}/debug/drivebus}
. bench/lib/run.sh

cat >"$TMP/hold.py" <<'PY'
# Opens N connections to PORT from 127.0.0.2 and holds them; prints how many the server left open.
import resource, socket, sys, time
port, n = int(sys.argv[1]), int(sys.argv[2])
soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
socks, failed = [], 0
for _ in range(n):
    s = socket.socket()
    # The port is chosen at connect (IP_BIND_ADDRESS_NO_PORT), and one in TIME_WAIT from an
    # earlier run may be taken again.
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.setsockopt(socket.IPPROTO_IP, 24, 1)
    s.bind(("127.0.0.2", 0))
    try:
        s.connect(("127.0.0.1", port))
        socks.append(s)
    except OSError:
        failed += 1
        s.close()
time.sleep(3)
open_ = 0
for s in socks:
    s.setblocking(False)
    try:
        open_ += 1 if s.recv(1, socket.MSG_PEEK) else 0
    except BlockingIOError:
        open_ += 1
    except OSError:
        pass
print(f"{len(socks)} connected ({failed} failed), {open_} still open after 3 s", flush=True)
time.sleep(3600)
PY

cat >"$TMP/probe.py" <<'PY'
# From 127.0.0.3: an HTTP GET and a Modbus TCP read, timed; a half-sent header, timed to its close.
import socket, struct, sys, time
hp, mp = int(sys.argv[1]), int(sys.argv[2])
def conn(port):
    s = socket.socket(); s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1); s.bind(("127.0.0.3", 0)); s.settimeout(10); s.connect(("127.0.0.1", port)); return s
def timed(what, f):
    t = time.monotonic()
    try:
        r = f()
        print(f"  {what}: {r} in {1000 * (time.monotonic() - t):.0f} ms")
    except Exception as e:
        print(f"  {what}: failed after {1000 * (time.monotonic() - t):.0f} ms ({e!r})")
def http():
    s = conn(hp); s.sendall(b"GET /api/drives/conveyor-1 HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
    return s.recv(64).split(b"\r\n")[0].decode()
def modbus():
    s = conn(mp); s.sendall(struct.pack(">HHHBBHH", 1, 0, 6, 1, 4, 0, 1))
    return f"function {s.recv(64)[7]:#04x}"
def half():
    s = conn(hp); s.settimeout(60); s.sendall(b"GET /api/drives HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
    return "closed" if s.recv(64) == b"" else "answered"
timed("HTTP GET from 127.0.0.3", http)
timed("Modbus TCP read from 127.0.0.3", modbus)
timed("half-sent header from 127.0.0.3", half)
PY

run() {
  local label=$1 limits=$2
  printf 'name = "demo"\n[limits]\n%b\n' "$limits" >"$TMP/limits.toml"
  python3 - "$TMP/limits.toml" "$TMP/plant.toml" <<'PY'
import sys
demo = open("crates/gateway/src/demo.toml").read().replace('name = "demo"\n', open(sys.argv[1]).read(), 1)
open(sys.argv[2], "w").write(demo)
PY
  local hp mp
  hp=$(free_port); mp=$(free_port)
  (ulimit -n 20000; exec "$BIN" serve --config "$TMP/plant.toml" --no-store --no-opcua --http "127.0.0.1:$hp" --modbus "127.0.0.1:$mp") >"$TMP/gw.log" 2>&1 &
  local gw=$!; PIDS+=("$gw")
  wait_port "$hp"; wait_port "$mp"; sleep 1
  echo "$label:"
  python3 "$TMP/hold.py" "$hp" 10000 >"$TMP/hold1.txt" 2>&1 & local h1=$!; PIDS+=("$h1")
  python3 "$TMP/hold.py" "$hp" 10000 >"$TMP/hold2.txt" 2>&1 & local h2=$!; PIDS+=("$h2")
  for _ in $(seq 1 600); do
    [ -s "$TMP/hold1.txt" ] && [ -s "$TMP/hold2.txt" ] && break
    sleep 0.5
  done
  echo "  from 127.0.0.2: $(cat "$TMP/hold1.txt"); $(cat "$TMP/hold2.txt")"
  echo "  the gateway holds $(ls /proc/$gw/fd | wc -l) descriptors"
  python3 "$TMP/probe.py" "$hp" "$mp"
  echo "  its log: $(grep -c . "$TMP/gw.log") lines; $(grep -m1 'refused [0-9]* connection' "$TMP/gw.log" || true)"
  stop "$h1"; stop "$h2"; stop "$gw"
}

run "before (no per-address limit, no reserve, no timeouts)" \
  'per_address = 1000000\nreserve_fds = 0\nidle_timeout_s = 0\nheader_timeout_ms = 600000'
run "after (defaults)" ''
