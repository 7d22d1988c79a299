#!/usr/bin/env python3
"""Interop witness: pymodbus (a Modbus stack nobody here wrote) talks to the gateway's Modbus TCP
server running the demo (docs/register-map.md).

usage: pymodbus_gateway.py PORT

Reads the ten input registers of units 1..10 and checks the family and bus address of each,
writes fan-1's (unit 3) setpoint = 3000 (30.00 Hz) and command word = 1 (run) and sees the
status word say running and the output frequency rise, reads ahu-1's (unit 7) first parameter
from the window at 1000/1001, and checks that an unknown unit gets exception 0B.
Exit status 0 on success; a one-line reason on stderr otherwise.
"""
import sys
import time

from pymodbus.client import ModbusTcpClient

# unit: (family code, bus address) in the demo
DEMO = {1: (1, 1), 2: (1, 2), 3: (1, 3), 4: (2, 1), 5: (2, 2), 6: (2, 3), 7: (3, 1), 8: (3, 2), 9: (4, 1), 10: (4, 2)}


def fail(msg):
    print(f"pymodbus_gateway: {msg}", file=sys.stderr)
    sys.exit(1)


def unit_kw(unit):
    # pymodbus 3.9 renamed slave= to device_id=.
    import inspect
    params = inspect.signature(ModbusTcpClient.read_input_registers).parameters
    return {"device_id": unit} if "device_id" in params else {"slave": unit}


def main():
    port = int(sys.argv[1])
    c = ModbusTcpClient("127.0.0.1", port=port, timeout=5, retries=1)
    if not c.connect():
        fail(f"cannot connect to 127.0.0.1:{port}")

    def inputs(unit, addr=0, count=10):
        r = c.read_input_registers(addr, count=count, **unit_kw(unit))
        if r.isError():
            fail(f"unit {unit}: read input registers {addr}+{count}: {r}")
        return r.registers

    deadline = time.time() + 30
    for unit, (family, address) in DEMO.items():
        while True:
            r = inputs(unit)
            if r[0] & 0x08:
                break
            if time.time() > deadline:
                fail(f"unit {unit} never online: {r}")
            time.sleep(0.1)
        if (r[8], r[9]) != (family, address):
            fail(f"unit {unit}: family/address {r[8]}/{r[9]}, expected {family}/{address}")

    for reg, value in ((1, 3000), (0, 1)):
        w = c.write_register(reg, value, **unit_kw(3))
        if w.isError():
            fail(f"unit 3: write {reg} = {value}: {w}")
    seen = []
    deadline = time.time() + 30
    while time.time() < deadline:
        r = inputs(3, 0, 3)
        if r[0] & 0x01 and r[2] == 3000:
            seen.append(r[1])
            if len(seen) >= 3 and seen[-1] > seen[0]:
                break
        time.sleep(0.1)
    else:
        fail(f"fan-1 did not run toward 30 Hz: {seen}")

    h = c.read_holding_registers(0, count=2, **unit_kw(3))
    if h.isError() or h.registers != [1, 3000]:
        fail(f"unit 3 holding 0..1: {h}")
    p = c.read_holding_registers(1000, count=2, **unit_kw(7))
    if p.isError():
        fail(f"unit 7 parameter 0: {p}")
    e = c.read_input_registers(0, count=1, **unit_kw(42))
    if not e.isError() or getattr(e, "exception_code", None) != 0x0B:
        fail(f"unit 42: expected exception 0B, got {e}")
    c.write_register(0, 0, **unit_kw(3))
    c.close()
    print(f"pymodbus: 10 units read; fan-1 output " + " ".join(f"{v / 100:.2f}" for v in seen[-3:]) + " Hz")


if __name__ == "__main__":
    main()
