#!/usr/bin/env bash
# Bus owner poll rate and utilization on the paced virtual line (simulated time).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo bench -p drivebus-link --bench poll_rate 2>/dev/null
