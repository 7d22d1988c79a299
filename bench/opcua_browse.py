#!/usr/bin/env python3
"""One OPC UA client walking the whole plant, for bench/scale.sh (asyncua).

    opcua_browse.py URL [CONCURRENCY]

Connects, browses the Drives folder (every drive's object), then for every drive browses its
children and reads its OutputFrequency (CONCURRENCY requests in flight, default 16). Prints one
JSON line: drives found, drives whose children were browsed, values read, of them with status
Good (the others Uncertain or Bad: docs/opcua.md), the seconds to connect and those the walk
took.
"""

import asyncio
import json
import sys
import time

from asyncua import Client, ua


async def main(url, concurrency):
    t0 = time.monotonic()
    c = Client(url, timeout=120)
    await c.connect()
    connect_s = time.monotonic() - t0
    try:
        ns = await c.get_namespace_index("urn:drivebus")
        t1 = time.monotonic()
        folder = c.get_node(f"ns={ns};s=Drives")
        drives = await folder.get_children()
        browsed = read = good = 0
        gate = asyncio.Semaphore(concurrency)

        async def walk(drive):
            nonlocal browsed, read, good
            async with gate:
                children = await drive.get_children()
                if children:
                    browsed += 1
                # The drive's node id is `Drives/<name>`: its variables' ids follow from it.
                var = c.get_node(f"ns={ns};s={drive.nodeid.Identifier}/OutputFrequency")
                dv = await var.read_data_value(raise_on_bad_status=False)
                if dv.Value is not None and dv.Value.Value is not None:
                    read += 1
                if dv.StatusCode_ is None or dv.StatusCode_.is_good():
                    good += 1

        await asyncio.gather(*(walk(d) for d in drives))
        walk_s = time.monotonic() - t1
    finally:
        await c.disconnect()
    print(json.dumps({"drives": len(drives), "browsed": browsed, "read": read, "good": good,
                      "connect_s": round(connect_s, 2), "walk_s": round(walk_s, 2)}), flush=True)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 16))
