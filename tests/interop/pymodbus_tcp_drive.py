#!/usr/bin/env python3
"""Interop witness: a pymodbus Modbus TCP server (MBAP, as a drive with an Ethernet card) holding
the registers of the small drive tests/interop/pymodbus-drive.toml describes, at unit id 7:

  0  status (bit 0 running, bit 1 reverse)     10  command (1 run, 0 stop, 2 reverse)
  1  output frequency, 0.01 Hz                 11  setpoint, 0.01 Hz
  2  set frequency, 0.01 Hz                    20  acceleration time, 0.1 s (a parameter)
  3  output current, 0.1 A

A write to 10 or 11 acts at once: the output follows the setpoint while running (no ramp), so
what a master commanded shows in the next read. Prints "listening on PORT" when ready.

usage: pymodbus_tcp_drive.py PORT
"""
import asyncio
import sys

from pymodbus.server import StartAsyncTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice
from pymodbus.framer import FramerType


async def act(function_code, start_address, address, count, regs, set_values):
    """Before a write is stored: what the drive does with it (the registers changed in place)."""
    if set_values is None:
        return None
    for i, v in enumerate(set_values):
        r = address + i - start_address
        if address + i == 10:
            running = v in (1, 2)
            regs[0 - start_address] = (1 if running else 0) | (2 if v == 2 else 0)
        if address + i == 11:
            regs[2 - start_address] = v
    running = regs[0 - start_address] & 1
    regs[1 - start_address] = regs[2 - start_address] if running else 0
    regs[3 - start_address] = 42 if running else 0
    return None


async def main():
    port = int(sys.argv[1])
    regs = [0] * 32
    regs[20] = 100  # acceleration time 10.0 s
    device = SimDevice(id=7, simdata=[SimData(0, count=32, values=regs, datatype=DataType.REGISTERS)], action=act)
    print(f"listening on {port}", flush=True)
    await StartAsyncTcpServer(context=device, address=("127.0.0.1", port), framer=FramerType.SOCKET)


if __name__ == "__main__":
    asyncio.run(main())
