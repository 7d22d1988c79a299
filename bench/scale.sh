#!/usr/bin/env bash
# A big plant on one box (issue 25), not run in CI.
#
# For each plant size in $PLANTS (default "1000 10000"): 1000 simulated drives on 32 virtual
# buses (polled every 500 ms) or 10 000 on 320 (polled every second), generated
# (bench/lib/plant.sh's write_scale_plant), served by the release binary with every front end
# on: HTTP, Modbus TCP, OPC UA, MQTT and a Sparkplug B edge node (both to a Mosquitto started
# here on a free port), and a store. Printed, one column per plant:
#   - time to listeners up: from the start until /readyz answers 200 (HTTP, Modbus TCP and
#     OPC UA listening, the store writable);
#   - time to every drive online: until /metrics has drivebus_drive_online 1 for every drive;
#   - RSS $SETTLE_SECS s after the start (default 60), and the CPU share over the next
#     $CPU_SECS s (default 20; % of one core);
#   - /metrics scrape p50/p99 over $SCRAPES scrapes one after another (default 200);
#   - the time one OPC UA client (asyncua, bench/opcua_browse.py) takes to browse every drive
#     and read the OutputFrequency of each, within $OPCUA_TIMEOUT s (default 600);
#   - RSS with $SUB_CLIENTS OPC UA clients (default 20, one process each,
#     bench/opcua_subscriber.py) subscribed to 6 variables of drives vfd-1..vfd-1000 (6000
#     monitored items each), once all are subscribed or after $SUB_TIMEOUT s (default 600).
# A phase that does not finish in its time ($LISTEN_TIMEOUT, $ONLINE_TIMEOUT, $OPCUA_TIMEOUT,
# $SUB_TIMEOUT) says so in the table; the script always ends. BIN=path measures that build of
# drivebus instead of building the release one here.
#
# A short run: PLANTS=1000 SETTLE_SECS=15 CPU_SECS=5 SCRAPES=50 SUB_CLIENTS=2 bench/scale.sh
set -euo pipefail
cd "$(dirname "$0")/.."
. bench/lib/plant.sh
PLANTS=${PLANTS:-"1000 10000"}
SETTLE_SECS=${SETTLE_SECS:-60}
CPU_SECS=${CPU_SECS:-20}
SCRAPES=${SCRAPES:-200}
LISTEN_TIMEOUT=${LISTEN_TIMEOUT:-120}
ONLINE_TIMEOUT=${ONLINE_TIMEOUT:-300}
OPCUA_TIMEOUT=${OPCUA_TIMEOUT:-600}
SUB_CLIENTS=${SUB_CLIENTS:-20}
SUB_TIMEOUT=${SUB_TIMEOUT:-600}

for p in mosquitto python3 curl; do
  command -v "$p" >/dev/null || { echo "$p is missing (.ci/install-witnesses.sh)" >&2; exit 1; }
done
python3 -c 'import asyncua' 2>/dev/null || { echo "asyncua is missing (.ci/install-witnesses.sh)" >&2; exit 1; }

# BIN: another build of drivebus to measure (default: the release build, built here).
if [ -z "${BIN:-}" ]; then
  cargo build --release -q -p drivebus
  BIN=target/release/drivebus
fi
. bench/lib/run.sh
HZ=$(getconf CLK_TCK)
now() { date +%s.%N; }
# Seconds since $1 (a `now`), to 0.1 s.
since() { python3 -c "print(round($(now) - $1, 1))"; }

# One broker for MQTT and Sparkplug B, loopback only.
BP=$(free_port)
printf 'listener %d 127.0.0.1\nallow_anonymous true\npersistence false\n' "$BP" >"$TMP/mosquitto.conf"
mosquitto -c "$TMP/mosquitto.conf" >"$TMP/mosquitto.log" 2>&1 &
PIDS+=("$!")
wait_port "$BP"
BROKER="mqtt://127.0.0.1:$BP"

ROWS="$TMP/rows"
: >"$ROWS"
row() { printf '%s\t%s\t%s\n' "$1" "$2" "$3" >>"$ROWS"; }   # row PLANT WHAT VALUE

# Drives with drivebus_drive_online 1 in one scrape of port $1 (0 when the scrape fails).
online_count() { curl -s -m 30 "http://127.0.0.1:$1/metrics" | grep -c '^drivebus_drive_online{.*} 1$' || true; }

run_plant() {
  local drives=$1 buses=$2 poll=$3
  local dir="$TMP/plant-$drives"
  mkdir -p "$dir"
  # Every subscriber is anonymous: one user, allowed as many sessions as there are clients.
  write_scale_plant "$dir/plant.toml" "$drives" "$buses" "$poll" \
    "$(printf '[store]\npath = "%s/drivebus.db"\n[opcua]\nmax_sessions_per_user = %d\n' "$dir" "$((SUB_CLIENTS + 1))")"
  local hp mp op t0 gw
  hp=$(free_port); mp=$(free_port); op=$(free_port)
  echo "== $drives drives on $buses virtual buses (poll ${poll} ms), every front end on"
  t0=$(now)
  "$BIN" serve --config "$dir/plant.toml" --http "127.0.0.1:$hp" --modbus "127.0.0.1:$mp" \
    --opcua "127.0.0.1:$op" --mqtt "$BROKER" --sparkplug "$BROKER" >"$dir/gw.log" 2>&1 &
  gw=$!; PIDS+=("$gw")

  local up="> ${LISTEN_TIMEOUT} s"
  while python3 -c "import sys; sys.exit(0 if $(now) - $t0 < $LISTEN_TIMEOUT else 1)"; do
    if [ "$(curl -s -o /dev/null -w '%{http_code}' -m 5 "http://127.0.0.1:$hp/readyz" || true)" = 200 ]; then
      up="$(since "$t0") s"; break
    fi
    kill -0 "$gw" 2>/dev/null || { echo "drivebus serve ended:" >&2; tail -5 "$dir/gw.log" >&2; return 1; }
    sleep 0.1
  done
  echo "listeners up: $up"; row "$drives" "listeners up (/readyz 200)" "$up"

  local online n=0
  online="> ${ONLINE_TIMEOUT} s"
  while python3 -c "import sys; sys.exit(0 if $(now) - $t0 < $ONLINE_TIMEOUT else 1)"; do
    n=$(online_count "$hp")
    if [ "$n" -ge "$drives" ]; then online="$(since "$t0") s"; break; fi
    sleep 1
  done
  [ "$n" -ge "$drives" ] || online="$online ($n of $drives online)"
  echo "every drive online: $online"; row "$drives" "every drive online" "$online"

  python3 -c "import time; time.sleep(max(0, $t0 + $SETTLE_SECS - $(now)))"
  local rss cpu c0 c1
  rss=$(rss_kb "$gw")
  echo "RSS after $SETTLE_SECS s: $((rss / 1024)) MiB"; row "$drives" "RSS after $SETTLE_SECS s" "$((rss / 1024)) MiB"
  c0=$(cpu_ticks "$gw"); sleep "$CPU_SECS"; c1=$(cpu_ticks "$gw")
  cpu=$(python3 -c "print(round(($c1 - $c0) * 100 / ($HZ * $CPU_SECS), 1))")
  echo "CPU over $CPU_SECS s: $cpu % of a core"; row "$drives" "CPU share (% of a core)" "$cpu %"

  local scrape
  scrape=$(python3 - "$hp" "$SCRAPES" <<'PY'
import http.client, sys, time
port, n = int(sys.argv[1]), int(sys.argv[2])
conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
times, size = [], 0
for _ in range(n):
    t = time.perf_counter()
    conn.request("GET", "/metrics")
    r = conn.getresponse()
    body = r.read()
    times.append(time.perf_counter() - t)
    assert r.status == 200, r.status
    size = len(body)
times.sort()
pct = lambda p: times[min(n - 1, int(p * n))] * 1000
print(f"p50 {pct(0.5):.1f} ms, p99 {pct(0.99):.1f} ms ({size // 1024} KiB)")
PY
)
  echo "/metrics: $scrape"; row "$drives" "/metrics scrape" "$scrape"

  local browse
  if browse=$(timeout "$OPCUA_TIMEOUT" python3 bench/opcua_browse.py "opc.tcp://127.0.0.1:$op" 2>"$dir/browse.err"); then
    browse=$(python3 -c "import json,sys; v=json.loads(sys.argv[1]); print(f\"{v['walk_s']} s ({v['drives']} drives, {v['browsed']} browsed, {v['read']} read, {v['good']} Good; connect {v['connect_s']} s)\")" "$browse")
  else
    browse="not done in ${OPCUA_TIMEOUT} s ($(tail -n 1 "$dir/browse.err" | cut -c1-80))"
  fi
  echo "OPC UA browse + read every drive: $browse"; row "$drives" "OPC UA: browse every drive, read one variable each" "$browse"

  local subs=() i ready=0 t1 sub
  t1=$(now)
  for i in $(seq 1 "$SUB_CLIENTS"); do
    python3 bench/opcua_subscriber.py "opc.tcp://127.0.0.1:$op" 1 "$SUB_TIMEOUT" 1000 1000 1000 >"$dir/sub-$i.log" 2>&1 &
    subs+=("$!"); PIDS+=("$!")
  done
  while python3 -c "import sys; sys.exit(0 if $(now) - $t1 < $SUB_TIMEOUT else 1)"; do
    ready=$(cat "$dir"/sub-*.log 2>/dev/null | grep -c '"ready"' || true)
    [ "$ready" -ge "$SUB_CLIENTS" ] && break
    sleep 1
  done
  rss=$(rss_kb "$gw")
  sub="$((rss / 1024)) MiB ($ready of $SUB_CLIENTS clients subscribed in $(since "$t1") s)"
  echo "RSS with $SUB_CLIENTS OPC UA clients x 6000 items: $sub"
  row "$drives" "RSS, $SUB_CLIENTS OPC UA clients x 6000 items" "$sub"
  for i in "${subs[@]}"; do kill "$i" 2>/dev/null || true; done
  for i in "${subs[@]}"; do wait "$i" 2>/dev/null || true; done
  stop "$gw"
}

for n in $PLANTS; do
  case $n in
    1000) run_plant 1000 32 500 ;;
    10000) run_plant 10000 320 1000 ;;
    *) echo "PLANTS: 1000 and/or 10000, not $n" >&2; exit 2 ;;
  esac
done

echo
echo "== $("$BIN" --version 2>/dev/null | head -n 1), $(nproc) cores"
python3 - "$ROWS" <<'PY'
import sys
rows = [l.rstrip("\n").split("\t") for l in open(sys.argv[1]) if l.strip()]
plants = list(dict.fromkeys(r[0] for r in rows))
whats = list(dict.fromkeys(r[1] for r in rows))
cell = {(r[0], r[1]): r[2] for r in rows}
print("| | " + " | ".join(f"{p} drives" for p in plants) + " |")
print("| --- |" + " --- |" * len(plants))
for w in whats:
    print(f"| {w} | " + " | ".join(cell.get((p, w), "") for p in plants) + " |")
PY
