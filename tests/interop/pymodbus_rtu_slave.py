#!/usr/bin/env python3
"""Interop witness: pymodbus (a Modbus stack nobody here wrote) as an RS-485 master reads the
gateway's unified register map from its Modbus RTU slave (docs/register-map.md).

usage: pymodbus_rtu_slave.py PORT UNIT FAMILY ADDRESS

Waits until UNIT is online (status word bit 3), checks its family and bus address (input
registers 8 and 9), reads the holding registers 0..1 and the first parameter of the window
(1000/1001), and checks that a write is refused with exception 01 (the slave is read-only).
The line runs at 19200 8N1 (a pty carries no parity bit; see pymodbus_client.py).
Exit status 0 on success; a one-line reason on stderr otherwise.
"""
import sys
import time

from pymodbus.client import ModbusSerialClient


def fail(msg):
    print(f"pymodbus_rtu_slave: {msg}", file=sys.stderr)
    sys.exit(1)


def main():
    port, unit, family, address = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    c = ModbusSerialClient(port, baudrate=19200, parity="N", stopbits=1, bytesize=8, timeout=2, retries=1)
    if not c.connect():
        fail(f"cannot open {port}")
    deadline = time.time() + 30
    while True:
        r = c.read_input_registers(0, count=10, device_id=unit)
        if r.isError():
            fail(f"unit {unit}: read input registers 0+10: {r}")
        if r.registers[0] & 0x08:
            break
        if time.time() > deadline:
            fail(f"unit {unit} never online: {r.registers}")
        time.sleep(0.1)
    if (r.registers[8], r.registers[9]) != (family, address):
        fail(f"unit {unit}: family/address {r.registers[8]}/{r.registers[9]}, expected {family}/{address}")
    h = c.read_holding_registers(0, count=2, device_id=unit)
    if h.isError():
        fail(f"unit {unit}: holding 0..1: {h}")
    p = c.read_holding_registers(1000, count=2, device_id=unit)
    if p.isError():
        fail(f"unit {unit}: parameter 0 at 1000/1001: {p}")
    w = c.write_register(1, 2500, device_id=unit)
    if not w.isError() or getattr(w, "exception_code", None) != 1:
        fail(f"unit {unit}: a write to the read-only slave was not refused with exception 01: {w}")
    print(f"unit {unit}: status {r.registers[0]:04X}, family {family}, address {address}, "
          f"holding {h.registers}, parameter 0 = {p.registers}; write refused (01)")


if __name__ == "__main__":
    main()
