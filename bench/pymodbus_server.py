#!/usr/bin/env python3
"""A pymodbus Modbus TCP server for bench/gateway_load.sh: ten input registers for any unit id.

usage: pymodbus_server.py PORT
"""
import asyncio
import sys

from pymodbus.datastore import ModbusDeviceContext, ModbusSequentialDataBlock, ModbusServerContext
from pymodbus.server import StartAsyncTcpServer


async def main():
    port = int(sys.argv[1])
    # pymodbus adds 1 to request addresses and its blocks start at 1 or above: the block starts
    # at 1 so that request address 0 is its first value.
    block = ModbusSequentialDataBlock(1, [i * 100 for i in range(10)])
    ctx = ModbusServerContext(devices=ModbusDeviceContext(ir=block), single=True)
    print(f"listening on 127.0.0.1:{port}", flush=True)
    await StartAsyncTcpServer(context=ctx, address=("127.0.0.1", port))


if __name__ == "__main__":
    asyncio.run(main())
