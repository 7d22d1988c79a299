#!/usr/bin/env python3
"""The Sparkplug side of bench/sparkplug.sh, on paho-mqtt and pysparkplug's Sparkplug B schema.

    sparkplug_load.py HOST:PORT rate SECS EDGE DRIVES
        waits for the NBIRTH and DBIRTH of DRIVES devices of edge node EDGE, then runs every
        drive by DCMD, its setpoint switching between 20 and 50 Hz every 6 s, and counts the
        DDATA messages of SECS seconds: prints {"ddata_per_s", "metrics_per_s", "seconds"}.
    sparkplug_load.py HOST:PORT drain HOST_ID EDGE COUNT
        says STATE online as primary host HOST_ID and times from the NBIRTH until COUNT
        historical DDATA messages have come: prints {"historical", "seconds", "per_s"}.
"""

import json
import sys
import threading
import time

import paho.mqtt.client as mqtt
from pysparkplug._protobuf import sparkplug_b_pb2 as pb


def main():
    host, port = sys.argv[1].rsplit(":", 1)
    mode = sys.argv[2]
    lock = threading.Lock()
    st = {"born": {}, "ddata": 0, "metrics": 0, "hist": 0, "nbirth_at": None, "done_at": None, "counting": False}
    edge = sys.argv[4]
    target = int(sys.argv[5])

    def on_message(client, userdata, msg):
        parts = msg.topic.split("/")
        if len(parts) < 4 or parts[3] != edge:
            return
        kind = parts[2]
        p = pb.Payload()
        p.ParseFromString(msg.payload)
        with lock:
            if kind == "NBIRTH" and st["nbirth_at"] is None:
                st["nbirth_at"] = time.monotonic()
            elif kind == "DBIRTH":
                st["born"][parts[4]] = {m.name: m.alias for m in p.metrics}
            elif kind == "DDATA":
                if st["counting"]:
                    st["ddata"] += 1
                    st["metrics"] += len(p.metrics)
                if p.metrics and p.metrics[0].is_historical:
                    st["hist"] += 1
                    if st["hist"] >= target and st["done_at"] is None:
                        st["done_at"] = time.monotonic()

    client = mqtt.Client(client_id=f"drivebus-bench-{mode}-{int(time.time())}", clean_session=True)
    client.on_message = on_message
    client.connect(host, int(port), keepalive=30)
    client.loop_start()
    client.subscribe("spBv1.0/#", qos=0)
    time.sleep(0.5)
    if mode == "drain":
        host_id = sys.argv[3]
        client.publish(f"spBv1.0/STATE/{host_id}",
                       json.dumps({"online": True, "timestamp": int(time.time() * 1000)}), qos=1, retain=True)
        seen, idle_since = -1, time.monotonic()
        while True:
            with lock:
                if st["done_at"] is not None:
                    break
                if st["hist"] != seen:
                    seen, idle_since = st["hist"], time.monotonic()
            if time.monotonic() - idle_since > 60:
                print(json.dumps({"historical": seen, "error": "nothing more for 60 s"}))
                sys.exit(1)
            time.sleep(0.05)
        with lock:
            secs = st["done_at"] - st["nbirth_at"]
            print(json.dumps({"historical": st["hist"], "seconds": round(secs, 2), "per_s": round(st["hist"] / secs)}))
        return
    secs = float(sys.argv[3])
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline:
        with lock:
            if len(st["born"]) >= target:
                break
        time.sleep(0.1)

    def command(device, name, kind, value):
        p = pb.Payload()
        m = p.metrics.add()
        m.alias = st["born"][device][name]
        if kind == "double":
            m.datatype, m.double_value = 10, value
        else:
            m.datatype, m.boolean_value = 11, value
        client.publish(f"spBv1.0/{sys.argv[6] if len(sys.argv) > 6 else 'drivebus'}/DCMD/{edge}/{device}",
                       p.SerializeToString(), qos=0)

    for d in list(st["born"]):
        command(d, "Setpoint", "double", 50.0)
        command(d, "Command/Run", "boolean", True)
    time.sleep(3)
    with lock:
        st["counting"] = True
    start = time.monotonic()
    hz = 20.0
    while time.monotonic() - start < secs:
        for d in list(st["born"]):
            command(d, "Setpoint", "double", hz)
        hz = 70.0 - hz
        time.sleep(min(6.0, max(0.0, secs - (time.monotonic() - start))))
    with lock:
        elapsed = time.monotonic() - start
        print(json.dumps({"ddata_per_s": round(st["ddata"] / elapsed), "metrics_per_s": round(st["metrics"] / elapsed),
                          "seconds": round(elapsed, 1)}))
    client.loop_stop()


if __name__ == "__main__":
    main()
