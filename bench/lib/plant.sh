# Sourced by the benchmarks: writes the configuration of a big plant, 1000 simulated generic
# drives on 32 virtual buses (115200 baud, poll POLL_MS, 500 ms unless given; 8 buses of 32
# drives, 24 of 31), named vfd-1..vfd-1000 on line-1..line-32.
#
# Such a line is full: a generic drive's status is two reads, each about 15 ms of line time (the
# manual's 10 ms of silence, the request, the drive's 3 ms reply delay, the reply), so a line
# reads some 34 statuses a second and its 31 or 32 drives are polled about once a second, not
# every 500 ms (drivebus_bus_poll_lag_seconds about 0.43 s; drivebus_bus_utilization, the wire
# bytes alone, 0.11). Every command is three more exchanges (its write and the refresh's two
# reads).
#
#   write_plant FILE [NAME] [EXTRA] [POLL_MS]   EXTRA: TOML put before the buses (tokens, ...)
write_plant() {
  local file="$1" name="${2:-load}" extra="${3:-}" poll="${4:-500}"
  {
    echo "name = \"$name\""
    printf '[http]\nanonymous_read = true\n'
    printf '%s\n' "$extra"
    local n=0 b a per
    for b in $(seq 1 32); do
      per=31; [ "$b" -le 8 ] && per=32   # 8 x 32 + 24 x 31 = 1000
      printf '[[bus]]\nname = "line-%d"\nport = "virtual"\nprotocol = "modbus-rtu"\nbaud = 115200\n' "$b"
      for a in $(seq 1 "$per"); do
        n=$((n + 1))
        printf '[[bus.drive]]\nname = "vfd-%d"\nfamily = "generic"\naddress = %d\npoll_ms = %d\n' "$n" "$a" "$poll"
      done
    done
  } >"$file"
}

# Writes the configuration of one virtual bus per drive family, DRIVES drives each (named
# generic-1.., toshiba-1.., danfoss-1.., b800-1..), at BAUD in each family's character format,
# every drive polled as often as the line allows (poll_ms = 10).
#
#   write_family_plant FILE BAUD DRIVES [EXTRA]   EXTRA: TOML put before the buses (tokens, ...)
write_family_plant() {
  local file="$1" baud="$2" drives="$3" extra="${4:-}"
  {
    echo 'name = "families"'
    printf '[http]\nanonymous_read = true\n'
    printf '%s\n' "$extra"
    local fam protocol serial a
    for spec in generic:modbus-rtu:8N2 toshiba:toshiba-binary:8E1 danfoss:danfoss-fc:8E1 b800:b800:8N1; do
      IFS=: read -r fam protocol serial <<<"$spec"
      printf '[[bus]]\nname = "line-%s"\nport = "virtual"\nprotocol = "%s"\nbaud = %d\nserial = "%s"\n' \
        "$fam" "$protocol" "$baud" "$serial"
      for a in $(seq 1 "$drives"); do
        printf '[[bus.drive]]\nname = "%s-%d"\nfamily = "%s"\naddress = %d\npoll_ms = 10\n' "$fam" "$a" "$fam" "$a"
      done
    done
  } >"$file"
}

# Writes the configuration of a plant of DRIVES simulated generic drives spread evenly over BUSES
# virtual buses (115200 baud, every drive polled every POLL_MS), named vfd-1..vfd-DRIVES on
# line-1..line-BUSES (bench/scale.sh: 1000 on 32, 10 000 on 320).
#
#   write_scale_plant FILE DRIVES BUSES POLL_MS [EXTRA]   EXTRA: TOML put before the buses
write_scale_plant() {
  local file="$1" drives="$2" buses="$3" poll="$4" extra="${5:-}"
  python3 - "$drives" "$buses" "$poll" "$extra" >"$file" <<'PY'
import sys
drives, buses, poll, extra = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
out = ['name = "scale"', '[http]', 'anonymous_read = true', extra]
n = 0
for b in range(buses):
    per = drives // buses + (1 if b < drives % buses else 0)
    out.append(f'[[bus]]\nname = "line-{b + 1}"\nport = "virtual"\nprotocol = "modbus-rtu"\nbaud = 115200')
    for a in range(1, per + 1):
        n += 1
        out.append(f'[[bus.drive]]\nname = "vfd-{n}"\nfamily = "generic"\naddress = {a}\npoll_ms = {poll}')
print("\n".join(out))
PY
}
