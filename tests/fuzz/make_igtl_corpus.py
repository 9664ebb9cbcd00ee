#!/usr/bin/python3
"""Writes the seed corpus of fuzz_igtl (tests/fuzz/corpus/igtl): OpenIGTLink streams built from
the protocol specification (openigtlink.org), with the message builders of
tests/haptics/test_igtl_python.py. Each file's first byte is the size - 1 of the pieces the
target feeds the rest in.   /usr/bin/python3 tests/fuzz/make_igtl_corpus.py (needs pytest, as that file does)"""
import struct
import sys
from pathlib import Path

here = Path(__file__).resolve().parent
sys.path.insert(0, str(here.parent / "haptics"))
from test_igtl_python import crc64, message, sensor, transform  # noqa: E402


def string(device: str, text: str) -> bytes:
    """STRING: uint16 encoding (3 = US-ASCII), uint16 length, the bytes."""
    return message("STRING", device, struct.pack(">HH", 3, len(text)) + text.encode())


def status(device: str, code: int, name: str, text: str) -> bytes:
    """STATUS: uint16 code, int64 subcode, char[20] error name, NUL-terminated message."""
    return message("STATUS", device,
                   struct.pack(">Hq20s", code, 0, name.encode()) + text.encode() + b"\0")


def bad_crc(msg: bytes) -> bytes:
    head = bytearray(msg[:58])
    head[57] ^= 0x5A  # the CRC-64 field's last byte
    return bytes(head) + msg[58:]


streams = {
    "transform.bin": (7, transform("guidewire", 120.0, 30.0)),
    "string_exchange.bin": (0, string("exchange", "add catheter-jl4-6f as catheter")),
    "status.bin": (15, status("device", 1, "OK", "ready")),
    "sensor_v2_two.bin": (57, sensor("vel_catheter", [5.0, -10.0], version=2)
                          + sensor("balloon", [8.0])),
    # An IMAGE's header declaring a body over the 64 KiB limit, the body cut short (the corpus
    # stays small; test_igtl_stream.cpp reads past a whole one).
    "oversized_cut.bin": (255, message("IMAGE", "volume", bytes(70000))[:58 + 300]),
    "bad_crc_then_transform.bin": (3, bad_crc(transform("catheter", 5.0, 0.0))
                                   + transform("catheter", 6.0, 90.0)),
}
assert crc64(b"123456789") == 0x6C40DF5F0B497347  # CRC-64/ECMA-182 check value
out = here / "corpus" / "igtl"
out.mkdir(parents=True, exist_ok=True)
for name, (piece, data) in streams.items():
    (out / name).write_bytes(bytes([piece]) + data)
    print(f"{out / name}: {1 + len(data)} bytes")
