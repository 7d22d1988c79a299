#!/usr/bin/env python3
"""OPC UA subscribers for bench/opcua.sh (asyncua).

    opcua_subscriber.py URL CLIENTS SECS PUBLISH_MS SAMPLE_MS DRIVES [LATENCIES_FILE]

Opens CLIENTS sessions; each subscribes to 6 variables of every drive vfd-1..vfd-DRIVES
(OutputFrequency, Setpoint, Current, Running, FaultCode, Online) with the given publishing and
sampling intervals, then counts notifications for SECS seconds. The latency of a notification is
the time it arrived minus its source timestamp (the time the drive answered the poll that
changed the value; same host, same clock); its server part is its server timestamp (when the
gateway handed the value to the subscriptions) minus its source timestamp. An item's first
notification (its initial value) is never counted (`late_initial_values`: how many arrived
after counting began). `not_good`: notifications whose status is not Good (a value gone stale
turns Uncertain, and that notification's latency is the value's age), by status in
`not_good_by_status`. Prints one JSON line,
with `cpu_pct`, this process's CPU over the counted SECS in % of a core (a subscriber short of
CPU queues what it receives, and that queueing is in its latencies). With LATENCIES_FILE, also
writes there every latency, those of Good values and every server part (seconds,
`{"latency": [...], "good": [...], "server": [...]}`), for bench/opcua.sh to merge the runs of
several processes.
"""

import asyncio
import json
import sys
import time

from asyncua import Client

VARS = ["OutputFrequency", "Setpoint", "Current", "Running", "FaultCode", "Online"]


class Handler:
    def __init__(self):
        self.latencies = []
        self.good = []
        self.server = []
        self.seen = set()
        self.counting = False
        self.late_initial = 0
        self.statuses = {}

    def datachange_notification(self, node, val, data):
        # An item's first notification is its initial value, not a change: never counted, even
        # when it arrives after counting started (many sessions subscribing at once).
        key = (id(data.subscription_data), data.monitored_item.ClientHandle)
        if key not in self.seen:
            self.seen.add(key)
            self.late_initial += self.counting
            return
        if not self.counting:
            return
        value = data.monitored_item.Value
        ts = value.SourceTimestamp
        if ts is not None:
            latency = time.time() - ts.timestamp()
            self.latencies.append(latency)
            # A value that went stale turns Uncertain (docs/opcua.md): that notification's
            # latency is the value's age, as it should be, not a delay.
            if value.StatusCode_ is None or value.StatusCode_.is_good():
                self.good.append(latency)
            else:
                name = value.StatusCode_.name
                self.statuses[name] = self.statuses.get(name, 0) + 1
            if value.ServerTimestamp is not None:
                self.server.append((value.ServerTimestamp - ts).total_seconds())


async def client(url, drives, publish_ms, sample_ms, handler, ready):
    c = Client(url, timeout=120)
    await c.connect()
    ns = await c.get_namespace_index("urn:drivebus")
    sub = await c.create_subscription(publish_ms, handler)
    nodes = [c.get_node(f"ns={ns};s=Drives/vfd-{i}/{v}") for i in range(1, drives + 1) for v in VARS]
    for k in range(0, len(nodes), 1000):
        await sub.subscribe_data_change(nodes[k:k + 1000], sampling_interval=sample_ms)
    ready.append(c)
    return c


async def main(url, clients, secs, publish_ms, sample_ms, drives, out=None):
    handler = Handler()
    ready = []
    t0 = time.monotonic()
    await asyncio.gather(*(client(url, drives, publish_ms, sample_ms, handler, ready) for _ in range(clients)))
    setup = time.monotonic() - t0
    # The first publishes carry every item's initial value (old source timestamps): not counted.
    await asyncio.sleep(3 * publish_ms / 1000 + 1)
    print(json.dumps({"ready": True, "setup_s": round(setup, 1)}), flush=True)
    handler.counting = True
    cpu0 = time.process_time()
    await asyncio.sleep(secs)
    cpu = time.process_time() - cpu0
    handler.counting = False
    lat = sorted(handler.latencies)
    pct = lambda p: round(lat[min(len(lat) - 1, int(p * len(lat)))] * 1000, 1) if lat else None
    print(json.dumps({
        "clients": clients, "items": clients * drives * len(VARS), "secs": secs,
        "notifications": len(lat), "per_s": round(len(lat) / secs),
        "latency_ms_p50": pct(0.50), "latency_ms_p99": pct(0.99), "latency_ms_max": pct(1.0),
        "cpu_pct": round(cpu * 100 / secs, 1), "not_good": len(lat) - len(handler.good),
        "late_initial_values": handler.late_initial, "not_good_by_status": handler.statuses,
    }), flush=True)
    if out:
        with open(out, "w") as f:
            json.dump({"latency": lat, "good": handler.good, "server": handler.server}, f)
    for c in ready:
        await c.disconnect()


if __name__ == "__main__":
    url, clients, secs, pub, samp, drives = sys.argv[1:7]
    out = sys.argv[7] if len(sys.argv) > 7 else None
    asyncio.run(main(url, int(clients), float(secs), float(pub), float(samp), int(drives), out))
