"""pymodbus client of bench/pty_clients.sh: reads 2 registers at 2100H from drive 1 (Modbus
RTU) in a tight loop for SECONDS and prints reads/s and latency percentiles."""
import sys
import time

from pymodbus.client import ModbusSerialClient


def main():
    port, seconds = sys.argv[1], float(sys.argv[2])
    client = ModbusSerialClient(port, baudrate=115200, bytesize=8, parity="N", stopbits=1, timeout=0.5, retries=0)
    if not client.connect():
        print(f"pymodbus_client: cannot open {port}", file=sys.stderr)
        sys.exit(2)
    lat, errors = [], 0
    start = time.perf_counter()
    end = start + seconds
    while time.perf_counter() < end:
        t0 = time.perf_counter()
        try:
            rr = client.read_holding_registers(0x2100, count=2, device_id=1)
            ok = not rr.isError() and len(rr.registers) == 2
        except Exception:  # noqa: BLE001 - a failed read is counted, not fatal
            ok = False
        if ok:
            lat.append(time.perf_counter() - t0)
        else:
            errors += 1
    elapsed = time.perf_counter() - start
    client.close()
    lat.sort()
    pct = lambda p: lat[min(int(len(lat) * p), len(lat) - 1)] * 1e6 if lat else 0.0
    print(
        f"pymodbus reads={len(lat)} errors={errors} seconds={elapsed:.2f} "
        f"reads_per_s={len(lat) / elapsed:.0f} p50_us={pct(0.5):.1f} p99_us={pct(0.99):.1f}"
    )


if __name__ == "__main__":
    main()
