# Sourced by the benchmarks: writes the configuration of a big plant, 1000 simulated generic
# drives on 32 virtual buses (115200 baud, poll 500 ms; 8 buses of 32 drives, 24 of 31), named
# vfd-1..vfd-1000 on line-1..line-32.
#
#   write_plant FILE [NAME] [EXTRA]   EXTRA: TOML put before the buses (tokens, [opcua], ...)
write_plant() {
  local file="$1" name="${2:-load}" extra="${3:-}"
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
        printf '[[bus.drive]]\nname = "vfd-%d"\nfamily = "generic"\naddress = %d\n' "$n" "$a"
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
