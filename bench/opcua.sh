#!/usr/bin/env bash
# The OPC UA front end under load (issue 15), not run in CI.
#
# `drivebus serve` (release, pinned to core 0) with 1000 simulated drives on 32 virtual buses,
# polled every $POLL_MS (default 1000), every drive ramping between speeds set over HTTP every
# few seconds so values keep changing. A bus of 31 or 32 generic drives at 115200 baud reads
# about 34 statuses a second (two reads a status, each behind the manual's 10 ms of silence):
# its drives are polled about once a second whatever poll_ms says, and the stirrer's commands
# (about 5 a second on each bus, three exchanges each) take a fifth of the line on top
# (bench/lib/plant.sh). At POLL_MS=500 a drive's values are then about 1 s old and pass three
# poll intervals (1.5 s), turning Uncertain in OPC UA, whenever commands crowd its bus: the
# latency p99 measured staleness, not delivery. 1000 polls the drives as often as before
# (the rate the line allows) with Uncertain only after 3 s.
# Then, for each client count in $CLIENTS (default "1 20"), that many asyncua sessions
# (bench/opcua_subscriber.py, core 1) subscribe to 6 variables of every drive (6000 monitored
# items each) with sampling $SAMPLE_MS (default 1000) and publishing $PUBLISH_MS (default 1000):
#   - the gateway's CPU over $SECS s, against the mean of the windows with no client just before
#     and just after (the drives' and the stirrer's own load moves);
#   - notifications/s and their latency from the drive's answer (source timestamp) to arrival
#     (an item's initial value not counted), the p99 of those with a Good status alone (a
#     value gone stale turns Uncertain: that notification's latency is the value's age),
#     and its server part: from the drive's answer to the gateway handing the value to the
#     subscriptions (server timestamp), the rest being the library's publishing, the network
#     and the subscriber's own queue;
#   - the gateway's RSS per client;
#   - the subscribers' side: their CPU (each process's own, summed, in % of a core) and how busy
#     core 1 was: near 100 % the subscribers queue what they receive and the latencies are theirs;
#   - the changes the OPC UA publisher fell behind on (drivebus_opcua_changes_lagged_total);
#   - the drives whose values are older than three poll intervals, sampled every 2 s
#     (drivebus_drive_data_age_seconds), with and without clients, and the buses' largest poll
#     lag then (drivebus_bus_poll_lag_seconds: above 0, the line does not keep $POLL_MS).
# The load average of the machine is printed next to each window (other work moves the figures:
# compare builds back to back).
#
# With ROUNDS=N (default 1) the client windows run N times each, a baseline between any two
# (B C B C ... B), and a last line per client count gives every round's CPU above its two
# baselines with their mean and median: one round's figure moves by a few points of a core
# with the stirrer's load and the machine's other work.
#
# SECS=20 CLIENTS="1 20" PUBLISH_MS=100 POLL_MS=1000 ROUNDS=3 bench/opcua.sh
# BIN=path measures that build of drivebus instead of building the release one here.
set -euo pipefail
cd "$(dirname "$0")/.."
. bench/lib/plant.sh
SECS=${SECS:-20}
CLIENTS=${CLIENTS:-"1 20"}
PUBLISH_MS=${PUBLISH_MS:-1000}
SAMPLE_MS=${SAMPLE_MS:-1000}
ROUNDS=${ROUNDS:-1}
POLL_MS=${POLL_MS:-1000}
TOKEN=bench-opcua-token-0123456789

# BIN: another build of drivebus to measure (default: the release build, built here).
if [ -z "${BIN:-}" ]; then
  cargo build --release -q -p drivebus
  BIN=target/release/drivebus
fi
. bench/lib/run.sh
HZ=$(getconf CLK_TCK)

# Every subscriber is anonymous: one user, allowed as many sessions as the most clients.
MAX_CLIENTS=$(printf '%s\n' $CLIENTS | sort -n | tail -n 1)
write_plant "$TMP/plant.toml" bench "$(printf '[store]\ndisabled = true\n[opcua]\nmax_sessions_per_user = %d\n[[token]]\nname = "bench"\ntoken = "%s"\nrole = "write"\n' "$((MAX_CLIENTS + 1))" "$TOKEN")" "$POLL_MS"
HP=$(free_port); MP=$(free_port); OP=$(free_port)
taskset -c 0 "$BIN" serve --config "$TMP/plant.toml" --http "127.0.0.1:$HP" --modbus "127.0.0.1:$MP" \
  --opcua "127.0.0.1:$OP" >"$TMP/gw.log" 2>&1 &
GW=$!; PIDS+=("$GW")
until grep -q "OPC UA" "$TMP/gw.log"; do sleep 0.2; done
URL="opc.tcp://127.0.0.1:$OP"

# Every drive running, its speed changed every 4 s (all values keep changing while they ramp).
# A command takes a bus exchange or two (tens of ms), so the stirrer sends from 32 threads, one
# per slice of the drives, or most drives would still stand when the measurement starts.
python3 - "$HP" "$TOKEN" >"$TMP/stir.log" 2>&1 <<'PY' &
import http.client, json, random, sys, threading, time
port, token = int(sys.argv[1]), sys.argv[2]
def stir(k):
    conn = http.client.HTTPConnection("127.0.0.1", port)
    def post(path, body=None):
        conn.request("POST", path, body=json.dumps(body) if body else None,
                     headers={"Authorization": f"Bearer {token}", "Content-Type": "application/json"})
        conn.getresponse().read()
    mine = range(1 + k, 1001, 32)
    for i in mine:
        post(f"/api/drives/vfd-{i}/speed", {"hz": 30})
        post(f"/api/drives/vfd-{i}/run")
    while True:
        for i in mine:
            post(f"/api/drives/vfd-{i}/speed", {"hz": random.choice([20, 30, 40, 50])})
        time.sleep(4)
for k in range(32):
    threading.Thread(target=stir, args=(k,), daemon=True).start()
while True:
    time.sleep(60)
PY
PIDS+=("$!")
sleep 15

# drivebus_opcua_changes_lagged_total now, or n/a for a build without it.
lagged() {
  curl -s "http://127.0.0.1:$HP/metrics" | awk '/^drivebus_opcua_changes_lagged_total / {v = $2} END {print (v == "" ? "n/a" : v)}'
}
# Busy and total ticks of core $1 so far (/proc/stat).
core_ticks() { awk -v c="cpu$1" '$1 == c {print $2 + $3 + $4 + $7 + $8, $2 + $3 + $4 + $5 + $6 + $7 + $8}' /proc/stat; }
# The load average over the last minute.
load() { cut -d' ' -f1 /proc/loadavg; }
# Drives whose values are older than three poll intervals now, and the buses' largest poll lag
# (s), from /metrics.
stale() {
  curl -s "http://127.0.0.1:$HP/metrics" | awk -v limit="$(awk -v p="$POLL_MS" 'BEGIN {print 3 * p / 1000}')" '
    /^drivebus_drive_data_age_seconds\{/ && $2 > limit {n++}
    /^drivebus_bus_poll_lag_seconds\{/ && $2 > lag {lag = $2}
    END {print n + 0, lag + 0}'
}
# Samples stale() every 2 s for $1 s; prints the mean and the most, and the largest poll lag.
stale_over() {
  local end=$((SECONDS + $1)) sum=0 k=0 most=0 lag=0 n l
  while [ "$SECONDS" -lt "$end" ]; do
    read -r n l < <(stale)
    sum=$((sum + n)); k=$((k + 1)); [ "$n" -gt "$most" ] && most=$n
    lag=$(awk -v a="$lag" -v b="$l" 'BEGIN {print (b > a ? b : a)}'); sleep 2
  done
  echo "stale drives (age > 3 x ${POLL_MS} ms, sampled every 2 s): mean $((sum / (k > 0 ? k : 1))), most $most; largest bus poll lag ${lag} s"
}
measure() {  # measure SECS: the gateway's CPU over SECS s, in % of one core
  local t0 t1
  t0=$(cpu_ticks "$GW"); sleep "$1"; t1=$(cpu_ticks "$GW")
  python3 -c "print(round(($t1 - $t0) * 100 / ($HZ * $1), 1))"
}
echo "== baseline: no OPC UA client, $SECS s"
stale_over "$SECS" &
BASE=$(measure "$SECS")
wait $!
RSS0=$(rss_kb "$GW")
echo "gateway CPU ${BASE} % of a core, RSS ${RSS0} kB, load average $(load)"

declare -A DELTAS
for r in $(seq 1 "$ROUNDS"); do
for n in $CLIENTS; do
  echo "== round $r: $n client(s) x 6000 monitored items (publishing ${PUBLISH_MS} ms, sampling ${SAMPLE_MS} ms), $SECS s"
  # One process per client (one asyncua session each), all on core 1.
  SUBS=()
  for i in $(seq 1 "$n"); do
    taskset -c 1 python3 bench/opcua_subscriber.py "$URL" 1 "$SECS" "$PUBLISH_MS" "$SAMPLE_MS" 1000 "$TMP/lat-$i.json" \
      >"$TMP/sub-$i.log" 2>&1 &
    SUBS+=("$!")
  done
  for i in $(seq 1 "$n"); do
    until grep -q '"ready"' "$TMP/sub-$i.log" 2>/dev/null || ! kill -0 "${SUBS[$((i - 1))]}" 2>/dev/null; do sleep 0.5; done
  done
  L0=$(lagged); C0=$(core_ticks 1)
  stale_over "$SECS" &
  STALE=$!
  CPU=$(measure "$SECS")
  wait "$STALE"
  L1=$(lagged); C1=$(core_ticks 1)
  RSS=$(rss_kb "$GW")
  for p in "${SUBS[@]}"; do wait "$p" || true; done
  python3 - "$TMP" "$n" "$SECS" "$L0" "$L1" "$C0 $C1" "$(load)" <<'PY'
import glob, json, sys
tmp, n, secs = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
l0, l1, (b0, t0, b1, t1), load = sys.argv[4], sys.argv[5], map(int, sys.argv[6].split()), sys.argv[7]
runs = [json.load(open(f)) for f in glob.glob(f"{tmp}/lat-*.json")]
lat = sorted(x for r in runs for x in r["latency"])
server = sorted(x for r in runs for x in r["server"])
good = sorted(x for r in runs for x in r["good"])
done = len(runs)
pct = lambda p, xs=lat: round(xs[min(len(xs) - 1, int(p * len(xs)))] * 1000, 1) if xs else None
cpu, late, statuses = [], 0, {}
for f in glob.glob(f"{tmp}/sub-*.log"):
    lines = [json.loads(x) for x in open(f) if x.startswith("{")]
    cpu += [x["cpu_pct"] for x in lines if "cpu_pct" in x]
    late += sum(x.get("late_initial_values", 0) for x in lines)
    for x in lines:
        for k, v in x.get("not_good_by_status", {}).items():
            statuses[k] = statuses.get(k, 0) + v
print(json.dumps({"clients": n, "clients_done": done, "notifications": len(lat), "per_s": round(len(lat) / secs),
                  "latency_ms_p50": pct(0.5), "latency_ms_p99": pct(0.99), "latency_ms_max": pct(1.0),
                  "not_good": len(lat) - len(good), "not_good_by_status": statuses, "good_latency_ms_p99": pct(0.99, good), "server_part_ms_p50": pct(0.5, server), "server_part_ms_p99": pct(0.99, server),
                  "server_part_ms_max": pct(1.0, server), "late_initial_values": late, "subscribers_cpu_pct": round(sum(cpu), 1), "core1_busy_pct": round((b1 - b0) * 100 / max(1, t1 - t0), 1),
                  "opcua_changes_lagged": "n/a" if "n/a" in (l0, l1) else int(float(l1) - float(l0)),
                  "load_avg": float(load)}))
PY
  rm -f "$TMP"/lat-*.json "$TMP"/sub-*.log
  # The load of the drives and of the HTTP stirrer moves: a baseline after as well as before.
  AFTER=$(measure "$SECS")
  python3 -c "b = ($BASE + $AFTER) / 2; print(f'gateway CPU {$CPU} % of a core; baselines {$BASE} and {$AFTER} %: {round($CPU - b, 1)} % above their mean; RSS {$RSS} kB, {round(($RSS - $RSS0) / $n)} kB per client')"
  DELTAS[$n]+="$(python3 -c "print(round($CPU - ($BASE + $AFTER) / 2, 1))") "
  BASE=$AFTER
done
done
for n in $CLIENTS; do
  python3 -c "import statistics as s; d = [float(x) for x in '${DELTAS[$n]}'.split()]; print(f'== {$n} client(s), {len(d)} round(s): gateway CPU above the baselines {d} % of a core, mean {round(s.mean(d), 1)}, median {round(s.median(d), 1)}')"
done
