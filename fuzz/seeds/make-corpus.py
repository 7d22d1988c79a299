#!/usr/bin/env python3
"""Writes the seed corpus of every fuzz target (fuzz/corpus/<target>/) from the manuals' frames
and the test vectors of protocols.md section 5. Each deframer seed is one control byte (its
direction and chunk size, see fuzz_targets/common.rs) and the bytes on the wire.

    python3 fuzz/seeds/make-corpus.py
"""
import hashlib
import os

HERE = os.path.dirname(os.path.abspath(__file__))
CORPUS = os.path.join(HERE, "..", "corpus")


def h(text):
    return bytes.fromhex(text.replace(" ", ""))


# (frame, who sent it): 1 master, 2 drive; the harness reads `ctl & 3` as the direction.
FRAMES = {
    "b800": [
        (h("7E 38 31 35 32 32 46 7F"), 1),
        (h("7E 38 35 35 30 30 39 36 30 35 45 7F"), 1),
        (h("7E 34 37 35 32 32 44 7F"), 1),
        (h("7E 34 37 35 33 32 43 7F"), 1),
        (h("7E 30 31 37 32 33 35 7F"), 2),
        (h("7E 30 35 37 30 33 33 7F"), 2),
    ],
    "toshiba_ascii": [
        (b"(RFE03)\r", 1),
        (b"(RFE03077B)\r", 2),
        (b"(W00100064)\r", 1),
        (b"(*2R0000)\r", 1),
        (b"(02R00000000)\r", 2),
        (b"(R11)\r", 1),
    ],
    "toshiba_binary": [
        (h("2F 52 00 00 81"), 1),
        (h("2F 57 00 10 00 64 FA"), 1),
        (h("2F 4E 00 00 7D"), 2),
        (h("2F 4E 00 01 7E"), 2),
        (h("2F 4E 00 04 81"), 2),
        (h("2F 58 02 05 C4 00 17 70 D8"), 1),
    ],
    "modbus_rtu": [
        (h("01 03 FD 00 00 01 B5 A6"), 1),
        (h("01 03 02 17 70 B6 50"), 2),
        (h("01 03 FD 00 00 02 F5 A7"), 1),
        (h("01 83 03 01 31"), 2),
        (h("01 06 FA 01 17 70 E6 C6"), 1),
        (h("01 2B 0E 01 00 70 77"), 1),
        (h("01 2B 0E 01 01 00 00 03 00 07 54 4F 53 48 49 42 41 01 0C 56 46 53 31 35 2D 32 30 33 37 50 4D 02 04 30 31 30 30 13 45"), 2),
        (h("11 03 00 6B 00 03 76 87"), 1),
        (h("01 03 21 04 00 00 0E 37"), 2),
        (h("01 06 00 02 13 88 25 5C"), 1),
    ],
    "modbus_ascii": [
        (b":010604051234AA\r\n", 1),
        (b":010321020002D7\r\n", 1),
        (b":010304010001F6\r\n", 1),
    ],
    "danfoss_fc": [
        (h("02 06 04 04 7C 20 00 58"), 1),
        (h("02 06 04 06 07 00 00 01"), 2),
        (h("02 0E 01 12 08 00 00 00 00 00 00 00 00 00 00 17"), 1),
        (h("02 0E 01 22 08 00 00 00 00 02 0C 06 07 00 00 28"), 2),
        (h("02 0E 01 06 4E 00 00 00 00 00 00 00 00 00 00 45"), 1),
    ],
}

# Modbus TCP requests as a client sends them (MBAP + PDU), one after the other.
MBAP = [
    h("00 01 00 00 00 06 01 03 00 00 00 02"),          # 03: command and setpoint
    h("00 02 00 00 00 06 03 04 00 00 00 0A"),          # 04: the input registers
    h("00 03 00 00 00 06 03 06 00 01 09 C4"),          # 06: setpoint 25.00 Hz
    h("00 04 00 00 00 0B 03 10 00 00 00 02 04 00 01 09 C4"),  # 16: run at 25.00 Hz
    h("00 05 00 00 00 0D 03 17 03 E8 00 02 00 01 00 01 02 09 C4"),  # 23: write, then read
    h("00 06 00 00 00 05 01 2B 0E 01 00"),             # 2B/0E: not served (01)
]

# Gateway configurations: the demo's shape and some of every section.
CONFIGS = [
    b'name = "hall-3"\n[http]\nlisten = "127.0.0.1:8080"\n[modbus]\nlisten = "127.0.0.1:5020"\nallow = ["127.0.0.1"]\n'
    b'[[bus]]\nname = "line-1"\nport = "virtual"\nprotocol = "modbus-rtu"\nbaud = 38400\n'
    b'[[bus.drive]]\nname = "fan-1"\nfamily = "generic"\naddress = 1\npoll_ms = 250\n',
    b'[[bus]]\nname = "a"\nport = "tcp://10.0.0.5:4001"\nprotocol = "danfoss-fc"\n[[bus.drive]]\nname = "ahu"\nfamily = "danfoss"\naddress = 3\nlocked = true\n',
    b'[[bus]]\nname = "t"\nport = "/dev/ttyUSB0"\nprotocol = "toshiba-binary"\nserial = "8E1"\ntimeout_ms = 200\nretries = 2\n[[bus.drive]]\nname = "p"\nfamily = "toshiba"\naddress = 0\n',
    b'[store]\npath = "drivebus.db"\n[mqtt]\nbroker = "127.0.0.1:1883"\n[limits]\nper_address = 64\n[[linkage]]\nfrom = "a"\nto = "b"\nratio = 0.5\n',
]


def write(target, name, data):
    d = os.path.join(CORPUS, target)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name + "-" + hashlib.sha1(data).hexdigest()[:12]), "wb") as f:
        f.write(data)


def main():
    for target, frames in FRAMES.items():
        stream = b""
        for i, (frame, who) in enumerate(frames):
            # Whole frame in one chunk (chunk size from ctl >> 2), and byte by byte.
            write(target, f"frame{i}", bytes([who | (63 << 2)]) + frame)
            write(target, f"bytewise{i}", bytes([who]) + frame)
            stream += frame
        write(target, "stream", bytes([0 | (63 << 2) | (1 << 5)]) + stream)
    for i, frame in enumerate(MBAP):
        write("modbus_tcp", f"request{i}", frame)
    write("modbus_tcp", "pipelined", b"".join(MBAP))
    for i, text in enumerate(CONFIGS):
        write("config", f"config{i}", text)


if __name__ == "__main__":
    main()
