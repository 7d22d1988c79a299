#!/usr/bin/env python3
"""Interop witness: pymodbus (a Modbus stack nobody here wrote) talks to a simulated drive.

usage: pymodbus_client.py generic|toshiba PORT

generic: reads 2103H (output frequency), writes 2001H = 4000 (40.00 Hz) and 2000H = 1 (run),
         and sees 2103H ramp up.
toshiba: reads FD00 (output frequency), writes FA01 = 4000 and FA00 = C400 (run with command
         and frequency priority), and sees FD00 ramp up.
Exit status 0 on success; a one-line reason on stderr otherwise.
"""
import sys
import time

from pymodbus.client import ModbusSerialClient

FAMILIES = {
    # name: (baud, parity, stopbits, unit, read reg, setpoint reg, command reg, run value)
    "generic": (9600, "N", 2, 1, 0x2103, 0x2001, 0x2000, 0x0001),
    # Parity "N": pyserial's exclusive lock (which pymodbus asks for) fails with EINVAL on a
    # Linux pty set to even parity; a pty carries no parity bit anyway, so the simulator is
    # started with --serial 8N1 for this witness (mbpoll checks 8E1).
    "toshiba": (19200, "N", 1, 1, 0xFD00, 0xFA01, 0xFA00, 0xC400),
}


def fail(msg):
    print(f"pymodbus_client: {msg}", file=sys.stderr)
    sys.exit(1)


def main():
    family, port = sys.argv[1], sys.argv[2]
    baud, parity, stop, unit, out_reg, set_reg, cmd_reg, run = FAMILIES[family]
    c = ModbusSerialClient(port, baudrate=baud, parity=parity, stopbits=stop, bytesize=8, timeout=1, retries=1)
    if not c.connect():
        fail(f"cannot open {port}")

    def read(reg):
        r = c.read_holding_registers(reg, count=1, device_id=unit)
        if r.isError():
            fail(f"read {reg:04X}: {r}")
        return r.registers[0]

    def write(reg, value):
        r = c.write_register(reg, value, device_id=unit)
        if r.isError():
            fail(f"write {reg:04X} = {value:04X}: {r}")

    start = read(out_reg)
    if start != 0:
        fail(f"a stopped drive reports output {start} at {out_reg:04X}")
    write(set_reg, 4000)
    write(cmd_reg, run)
    seen = []
    deadline = time.time() + 6
    while time.time() < deadline:
        seen.append(read(out_reg))
        if len(seen) >= 3 and seen[-1] > seen[-2] > seen[0] >= 0:
            print(f"{family}: output {out_reg:04X} ramps: " + " ".join(f"{v / 100:.2f}" for v in seen[-3:]) + " Hz")
            return
        time.sleep(0.3)
    fail(f"output {out_reg:04X} does not ramp: {seen}")


if __name__ == "__main__":
    main()
