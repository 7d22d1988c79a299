#!/usr/bin/env bash
# 32 virtual lines x 32 drives at 115200 baud under full polling, on simulated time:
# CPU per simulated second and memory per drive.  SIM_SECONDS=60 bench/sim_load.sh
set -euo pipefail
cd "$(dirname "$0")/.."
cargo bench -p drivebus-sim --bench sim_load 2>/dev/null
