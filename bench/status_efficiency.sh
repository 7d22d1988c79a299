#!/usr/bin/env bash
# Status at the fewest wire bytes (issue 18): `drivebus serve` with one virtual bus per drive
# family, $DRIVES drives each (default 8) at $BAUD (default 9600) in the family's character
# format, every drive running and polled as often as the line allows. Over $SECS s (default
# 20, after $WARM s of warm-up for the once-only reads) it reads /metrics twice and prints, per
# bus: drive status refreshes per second, full refreshes of the bus (every drive once) per
# second, and wire bytes per refresh, against the fewest-bytes plan the protocol allows
# (docs/status-efficiency.md): its bytes, and the rate it allows on the line with the
# protocol's gap and the simulated drives' 3 ms response time. Exit 1 when a bus is more than
# 10 % off the plan's rate or bytes.
#
# BAUD=9600 DRIVES=8 SECS=20 bench/status_efficiency.sh
set -euo pipefail
cd "$(dirname "$0")/.."
BAUD=${BAUD:-9600}
DRIVES=${DRIVES:-8}
SECS=${SECS:-20}
WARM=${WARM:-5}
TOKEN=bench-status-token-0123456789

cargo build --release -q -p drivebus
BIN=${CARGO_TARGET_DIR:-target}/release/drivebus

. bench/lib/run.sh
. bench/lib/plant.sh

write_family_plant "$TMP/plant.toml" "$BAUD" "$DRIVES" \
  "$(printf '[store]\ndisabled = true\n[[token]]\nname = "bench"\ntoken = "%s"\nrole = "write"\n' "$TOKEN")"
HP=$(free_port); MP=$(free_port)
"$BIN" serve --no-opcua --config "$TMP/plant.toml" --http "127.0.0.1:$HP" --modbus "127.0.0.1:$MP" >"$TMP/gw.log" 2>&1 &
GW=$!; PIDS+=("$GW")
wait_port "$HP"

post() {
  curl -sf -X POST -H "Authorization: Bearer $TOKEN" -H 'Content-Type: application/json' \
    ${2:+-d "$2"} "http://127.0.0.1:$HP/api/drives/$1" >/dev/null
}
for fam in generic toshiba danfoss b800; do
  for a in $(seq 1 "$DRIVES"); do
    post "$fam-$a/speed" '{"hz": 30}'
    post "$fam-$a/run"
  done
done
sleep "$WARM"

# scrape FILE: the metrics now, and the time they were read.
scrape() { date +%s.%N >"$1.t"; curl -sf "http://127.0.0.1:$HP/metrics" >"$1"; }
scrape "$TMP/m0"
sleep "$SECS"
scrape "$TMP/m1"
curl -sf "http://127.0.0.1:$HP/api/drives" >"$TMP/drives.json"
running=$(python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); print(sum(1 for x in d if x.get("running")), len(d))' "$TMP/drives.json")
stop "$GW"

echo "status_efficiency: $DRIVES drives per bus, $BAUD baud, ${SECS} s after ${WARM} s of warm-up; running drives: ${running% *} of ${running#* }"
awk -v dt="$(echo "$(cat "$TMP/m1.t") - $(cat "$TMP/m0.t")" | bc -l)" -v baud="$BAUD" -v drives="$DRIVES" '
  # The fewest-bytes plan of each family (docs/status-efficiency.md): bytes per status of a
  # running drive, exchanges, bits per character, the gap before each request in bits.
  BEGIN {
    split("generic toshiba danfoss b800", fams, " ")
    B["generic"] = 36; E["generic"] = 2; bits["generic"] = 11; gap["generic"] = 38.5   # RTU 8N2, t3.5
    B["toshiba"] = 31; E["toshiba"] = 2; bits["toshiba"] = 11; gap["toshiba"] = 44     # TIP binary 8E1, 4 chars
    B["danfoss"] = 32; E["danfoss"] = 1; bits["danfoss"] = 11; gap["danfoss"] = 22     # FC 8E1, 2 chars
    B["b800"]    = 60; E["b800"]    = 3; bits["b800"]    = 10; gap["b800"]    = 10     # B800 8N1, 1 char
    response = 0.003
  }
  # drivebus_drive_polls_total{bus="line-generic",drive="generic-1",family="generic"} 123
  function bus_of(line) { match(line, /bus="line-[a-z0-9]+"/); return substr(line, RSTART + 10, RLENGTH - 11) }
  FNR == 1 { file++ }
  /^drivebus_drive_polls_total\{/ { polls[file, bus_of($0)] += $NF }
  /^drivebus_drive_poll_errors_total\{/ { errors[file, bus_of($0)] += $NF }
  /^drivebus_bus_wire_bytes_total\{/ { bytes[file, bus_of($0)] = $NF }
  /^drivebus_bus_transactions_total\{/ { tx[file, bus_of($0)] = $NF }
  END {
    printf "%-8s %12s %8s %9s %10s %11s %11s %10s %11s %7s %8s\n", "family", "refreshes/s", "bus/s", "plan /s", "of plan", "bytes/refr", "plan bytes", "exch/refr", "plan exch", "errors", "verdict"
    bad = 0
    for (i = 1; i <= 4; i++) {
      f = fams[i]
      n = polls[2, f] - polls[1, f]
      if (n <= 0) { printf "%-8s no polls\n", f; bad = 1; continue }
      rate = n / dt
      per = bytes[2, f] - bytes[1, f]
      bpr = per / n
      t = (B[f] * bits[f] + E[f] * gap[f]) / baud + E[f] * response
      limit = 1 / t
      pct = 100 * rate / limit
      # Within 10 % of the plan, rate and bytes (the bytes differ only by the exchange in
      # flight at each reading).
      ok = (pct >= 90 && pct <= 110 && bpr >= 0.9 * B[f] && bpr <= 1.1 * B[f]) ? "ok" : "OFF"
      if (ok != "ok") bad = 1
      printf "%-8s %12.2f %8.3f %9.2f %9.1f%% %11.2f %11d %10.3f %11d %7d %8s\n", f, rate, rate / drives, limit, pct, bpr, B[f], (tx[2, f] - tx[1, f]) / n, E[f], errors[2, f] - errors[1, f], ok
    }
    exit bad
  }' "$TMP/m0" "$TMP/m1"
