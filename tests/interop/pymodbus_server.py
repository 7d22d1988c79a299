#!/usr/bin/env python3
"""Interop witness: a pymodbus server (RTU framing over TCP, as a serial device server presents
a drive) holding the generic drive's register map: 2000H command, 2001H frequency, 2100H-210BH
monitors (a drive running at 40.00 Hz, 5.2 A, version 1.00). Writes are stored, so a client can
read back what it wrote. Prints "listening on PORT" when ready.

usage: pymodbus_server.py PORT
"""
import asyncio
import sys

from pymodbus.datastore import ModbusDeviceContext, ModbusSequentialDataBlock, ModbusServerContext
from pymodbus.framer import FramerType
from pymodbus.server import StartAsyncTcpServer

# pymodbus data blocks number registers from 1: register N is at block address N + 1.
OFFSET = 1


async def main():
    port = int(sys.argv[1])
    regs = [0] * 0x2200
    regs[0x2101] = 0x0001          # status: running, forward
    regs[0x2102] = 4000            # set frequency 40.00 Hz
    regs[0x2103] = 4000            # output frequency 40.00 Hz
    regs[0x2104] = 52              # output current 5.2 A
    regs[0x2105] = 5400            # DC bus 540.0 V
    regs[0x210B] = 0x0100          # version 1.00
    block = ModbusSequentialDataBlock(OFFSET, regs)
    ctx = ModbusServerContext(devices={1: ModbusDeviceContext(hr=block)}, single=False)
    print(f"listening on {port}", flush=True)
    await StartAsyncTcpServer(context=ctx, address=("127.0.0.1", port), framer=FramerType.RTU)


if __name__ == "__main__":
    asyncio.run(main())
