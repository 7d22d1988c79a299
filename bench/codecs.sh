#!/usr/bin/env bash
# Parse and encode throughput of every wire format (criterion), summarised as a table.
#   bench/codecs.sh            # runs the benchmark, then prints the table
#   bench/codecs.sh --summary  # prints the table of the last run only
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "${1:-}" != "--summary" ]; then
  cargo bench -p drivebus-proto --bench codecs -- --noplot >/dev/null
fi
python3 - <<'PY'
import json, os
root = "target/criterion"
frames = 1024
sizes = {"modbus-rtu": 8, "modbus-ascii": 17, "toshiba-ascii": 8, "toshiba-binary": 5, "danfoss-fc": 8, "b800": 12}
targets = {"modbus-rtu": 30e6}
print(f"{'protocol':16} {'frame':>6} {'parse frames/s':>15} {'parse MB/s':>11} {'encode frames/s':>16} {'target':>8}")
for name, size in sizes.items():
    def est(group):
        p = os.path.join(root, group, name, "new", "estimates.json")
        with open(p) as f:
            return json.load(f)["mean"]["point_estimate"]  # ns per iteration
    parse_ns = est("parse_frames")
    enc_ns = est("encode_frames")
    fps = frames / (parse_ns * 1e-9)
    mbs = frames * size / (parse_ns * 1e-9) / 1e6
    efps = frames / (enc_ns * 1e-9)
    target = targets.get(name, 10e6)
    ok = "ok" if fps >= target else "BELOW"
    print(f"{name:16} {size:>5}B {fps/1e6:>13.1f} M {mbs:>9.0f}   {efps/1e6:>13.1f} M  {target/1e6:>4.0f} M {ok}")
print()
print("does a reply answer the request (the master's check before the profile parses it once):")
print(f"{'protocol':16} {'header look':>12} {'parse + match':>14}")
for name in sizes:
    def one(kind):
        p = os.path.join(root, "reply_matches", kind, name, "new", "estimates.json")
        if not os.path.exists(p):
            p = os.path.join(root, "reply_matches", f"{kind}_{name}", "new", "estimates.json")
        with open(p) as f:
            return json.load(f)["mean"]["point_estimate"]
    print(f"{name:16} {one('header'):>9.1f} ns {one('parse'):>11.1f} ns")
PY
