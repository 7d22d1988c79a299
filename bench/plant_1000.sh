#!/usr/bin/env bash
# Prints the benchmarks' plant: gateway NAME (default "load") with 1000 simulated generic drives
# on 32 virtual buses at 115200 baud (8 buses of 32, 24 of 31: vfd-1 .. vfd-1000), anonymous
# HTTP reads. Used by bench/gateway_load.sh and bench/sparkplug.sh.
#   bench/plant_1000.sh [NAME] > plant.toml
set -euo pipefail
echo "name = \"${1:-load}\""
printf '[http]\nanonymous_read = true\n'
n=0
for b in $(seq 1 32); do
  per=31; [ "$b" -le 8 ] && per=32   # 8 x 32 + 24 x 31 = 1000
  printf '[[bus]]\nname = "line-%d"\nport = "virtual"\nprotocol = "modbus-rtu"\nbaud = 115200\n' "$b"
  for a in $(seq 1 "$per"); do
    n=$((n + 1))
    printf '[[bus.drive]]\nname = "vfd-%d"\nfamily = "generic"\naddress = %d\n' "$n" "$a"
  done
done
