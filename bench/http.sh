#!/usr/bin/env bash
# HTTP API request handling in process (GET /api/drives/{id} through the whole router), requests/s.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo bench -p drivebus-gateway --bench http 2>/dev/null
