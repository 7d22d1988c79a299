#!/usr/bin/env python3
"""A Sparkplug B 3.0 host application for the gateway's tests, written on paho-mqtt and the
Sparkplug B schema as the pysparkplug package ships it (its compiled sparkplug_b_pb2), nothing
of drivebus's own.

    sparkplug_host.py HOST:PORT [--host-id ID]

It subscribes to spBv1.0/#, decodes every message and prints one JSON line per message on
stdout: {"type": "NBIRTH", "group", "edge", "device", "seq", "timestamp", "metrics": [{"name",
"alias", "value", "historical", "timestamp"}], "bdSeq"}. Names of DDATA metrics are resolved
through the aliases of the births. It checks what a host relies on and prints
{"type": "violation", "what": ...} for each breach:

- a message from an edge node whose NBIRTH it has not seen: it asks for a rebirth (NCMD)
  and ignores the node's messages until the NBIRTH;
- seq: NBIRTH has seq 0; every later NBIRTH/DBIRTH/DDATA/DDEATH/NDATA of the edge node has the
  previous seq + 1, wrapping at 256;
- aliases: unique across an edge node's NBIRTH and DBIRTHs, every DDATA alias was born for
  its device, and no DDATA or DDEATH comes for a device that is not born;
- NBIRTH carries bdSeq and Node Control/Rebirth = false, the latter without an alias (a host
  asks for a rebirth by name); NDEATH's bdSeq is the one of the last NBIRTH.

With --host-id it is a primary host: its STATE (retained, JSON) says online at start, with
the will saying offline. Commands on stdin, one per line:

    state online|offline                      publish this host's STATE
    dcmd EDGE DEVICE NAME TYPE VALUE          a DCMD by alias (TYPE: double, boolean, string)
    ncmd EDGE rebirth                         Node Control/Rebirth = true
    raw TOPIC HEX                             publish bytes as they are
    quit
"""

import json
import sys
import threading
import time

import paho.mqtt.client as mqtt
from pysparkplug._protobuf import sparkplug_b_pb2 as pb

OUT = threading.Lock()
BOOLEAN, DOUBLE, STRING, UINT64 = 11, 10, 12, 8


def emit(obj):
    with OUT:
        sys.stdout.write(json.dumps(obj) + "\n")
        sys.stdout.flush()


def violation(what):
    emit({"type": "violation", "what": what})


def value_of(m):
    if m.is_null:
        return None
    kind = m.WhichOneof("value")
    return getattr(m, kind) if kind else None


class Node:
    def __init__(self):
        self.seq = None
        self.bd_seq = None
        self.names = {}  # alias -> (device or None, name)
        self.born = set()
        self.by_name = {}  # (device, name) -> (alias, datatype)
        self.asked = False


NODES = {}


def on_message(client, userdata, msg):
    parts = msg.topic.split("/")
    if parts[0] != "spBv1.0" or parts[1] == "STATE" or len(parts) < 4:
        return
    group, kind, edge = parts[1], parts[2], parts[3]
    device = parts[4] if len(parts) > 4 else None
    if kind in ("NCMD", "DCMD"):
        return
    p = pb.Payload()
    try:
        p.ParseFromString(msg.payload)
    except Exception as e:  # noqa: BLE001 - any decode error is a finding
        violation(f"{msg.topic}: not a Sparkplug B payload: {e}")
        return
    key = (group, edge)
    node = NODES.setdefault(key, Node())
    seq = p.seq if p.HasField("seq") else None
    if kind == "NBIRTH":
        node.names, node.born, node.by_name = {}, set(), {}
        if seq != 0:
            violation(f"{msg.topic}: NBIRTH seq {seq}, not 0")
        node.seq = seq
    elif kind != "NDEATH":
        if node.seq is None:
            # Joined after the births, as a host that starts late does: ask for a rebirth once.
            if not node.asked:
                node.asked = True
                rebirth(client, group, edge)
            return
        if seq != (node.seq + 1) % 256:
            violation(f"{msg.topic}: seq {seq} after {node.seq}")
        node.seq = seq
    metrics = []
    for m in p.metrics:
        name = m.name if m.HasField("name") else None
        alias = m.alias if m.HasField("alias") else None
        if kind in ("NBIRTH", "DBIRTH") and alias is not None:
            if alias in node.names and node.names[alias] != (device, name):
                violation(f"{msg.topic}: alias {alias} of {name} is {node.names[alias]} already")
            node.names[alias] = (device, name)
            node.by_name[(device, name)] = (alias, m.datatype)
        if name is None and alias is not None:
            owner = node.names.get(alias)
            if owner is None or owner[0] != device:
                violation(f"{msg.topic}: alias {alias} was not born for {device}")
            else:
                name = owner[1]
        metrics.append({
            "name": name,
            "alias": alias,
            "value": value_of(m),
            "historical": m.is_historical,
            "timestamp": m.timestamp,
        })
    by_name = {m["name"]: m["value"] for m in metrics}
    line = {"type": kind, "group": group, "edge": edge, "device": device, "seq": seq,
            "timestamp": p.timestamp, "metrics": metrics, "bdSeq": by_name.get("bdSeq")}
    if kind == "NBIRTH":
        if "bdSeq" not in by_name:
            violation(f"{msg.topic}: NBIRTH without bdSeq")
        if by_name.get("Node Control/Rebirth") is not False:
            violation(f"{msg.topic}: NBIRTH without Node Control/Rebirth = false")
        rebirth = next((m for m in metrics if m["name"] == "Node Control/Rebirth"), None)
        if rebirth is not None and rebirth["alias"] is not None:
            violation(f"{msg.topic}: Node Control/Rebirth has alias {rebirth['alias']}")
        node.bd_seq = by_name.get("bdSeq")
    elif kind == "NDEATH":
        if by_name.get("bdSeq") != node.bd_seq:
            violation(f"{msg.topic}: NDEATH bdSeq {by_name.get('bdSeq')}, the NBIRTH had {node.bd_seq}")
    elif kind == "DBIRTH":
        node.born.add(device)
    elif kind in ("DDATA", "DDEATH"):
        if device not in node.born:
            violation(f"{msg.topic}: {kind} for a device not born")
        if kind == "DDEATH":
            node.born.discard(device)
    emit(line)


def rebirth(client, group, edge):
    p = pb.Payload()
    p.timestamp = int(time.time() * 1000)
    m = p.metrics.add()
    m.name, m.datatype, m.boolean_value = "Node Control/Rebirth", BOOLEAN, True
    client.publish(f"spBv1.0/{group}/NCMD/{edge}", p.SerializeToString(), qos=0)


def state(client, host_id, online):
    body = json.dumps({"online": online, "timestamp": int(time.time() * 1000)})
    client.publish(f"spBv1.0/STATE/{host_id}", body, qos=1, retain=True).wait_for_publish()


def command(client, host_id, words):
    if words[0] == "state":
        state(client, host_id, words[1] == "online")
    elif words[0] == "dcmd":
        _, edge, device, name, typ, text = words[:6]
        node = next((n for (g, e), n in NODES.items() if e == edge), None)
        p = pb.Payload()
        p.timestamp = int(time.time() * 1000)
        m = p.metrics.add()
        born = node.by_name.get((device, name)) if node else None
        if born:
            m.alias = born[0]
        else:
            m.name = name
        if typ == "double":
            m.datatype, m.double_value = DOUBLE, float(text)
        elif typ == "boolean":
            m.datatype, m.boolean_value = BOOLEAN, text == "true"
        else:
            m.datatype, m.string_value = STRING, text
        group = next((g for (g, e) in NODES if e == edge), "drivebus")
        client.publish(f"spBv1.0/{group}/DCMD/{edge}/{device}", p.SerializeToString(), qos=0)
    elif words[0] == "ncmd":
        edge = words[1]
        rebirth(client, next((g for (g, e) in NODES if e == edge), "drivebus"), edge)
    elif words[0] == "raw":
        client.publish(words[1], bytes.fromhex(words[2]) if len(words) > 2 else b"", qos=0)
    emit({"type": "done", "command": words[0]})


def main():
    host, port = sys.argv[1].rsplit(":", 1)
    host_id = sys.argv[sys.argv.index("--host-id") + 1] if "--host-id" in sys.argv else None
    client = mqtt.Client(client_id=f"sparkplug-host-{host_id or 'observer'}-{int(time.time() * 1000)}",
                         clean_session=True)
    if host_id:
        client.will_set(f"spBv1.0/STATE/{host_id}",
                        json.dumps({"online": False, "timestamp": int(time.time() * 1000)}),
                        qos=1, retain=True)
    subscribed = threading.Event()
    client.on_subscribe = lambda *a: subscribed.set()
    client.on_message = on_message
    client.connect(host, int(port), keepalive=15)
    client.loop_start()
    client.subscribe("spBv1.0/#", qos=0)
    subscribed.wait(30)
    if host_id:
        state(client, host_id, True)
    emit({"type": "ready"})
    for line in sys.stdin:
        words = line.split()
        if not words:
            continue
        if words[0] == "quit":
            break
        try:
            command(client, host_id, words)
        except Exception as e:  # noqa: BLE001 - a bad test line is reported, not fatal
            emit({"type": "error", "what": f"{line.strip()}: {e}"})
    client.loop_stop()
    client.disconnect()


if __name__ == "__main__":
    main()
