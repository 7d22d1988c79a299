#!/usr/bin/env bash
# Store throughput: durable events/s (each record() is one synced commit) from 1 and 4 threads,
# trend samples/s through the queue and batch writer, and the CLI's query times.
#   bench/store.sh          # store file under target/store-bench (the project's disk)
#   bench/store.sh DIR      # store file in DIR (put it on the disk the gateway will use)
set -euo pipefail
cd "$(dirname "$0")/.."
cargo run --quiet --release -p drivebus-store --example store_bench -- "${1:-target/store-bench}"
