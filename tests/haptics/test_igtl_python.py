"""`vcsim run --device igtl` against an OpenIGTLink client written from the protocol specification
(openigtlink.org, "OpenIGTLink Protocol": the 58-byte header, header version 2's extended header,
SENSOR, TRANSFORM, IMAGE), with the standard library only, as a device vendor's or a 3D Slicer
user's client would be: nothing here comes from the OpenIGTLink library the server uses.

Run by ctest: VCSIM_CLI=build/bin/vcsim python3 -m pytest test_igtl_python.py. Every wait is
bounded and generous (a loaded machine); nothing asserts on timing.
"""

import json
import math
import os
import re
import signal
import socket
import struct
import subprocess
import time
from pathlib import Path

import pytest

# --- the protocol ----------------------------------------------------------------------------

HEADER = struct.Struct(">H12s20sQQQ")  # version, type, device, time stamp, body size, CRC-64
assert HEADER.size == 58

# CRC-64 as the specification gives it: ECMA-182, polynomial 0x42F0E1EBA9EA3693, initial value
# 0, not reflected, no final XOR.
_POLY = 0x42F0E1EBA9EA3693
_TABLE = []
for _b in range(256):
    _c = _b << 56
    for _ in range(8):
        _c = ((_c << 1) ^ _POLY) if _c & (1 << 63) else (_c << 1)
    _TABLE.append(_c & 0xFFFFFFFFFFFFFFFF)


def crc64(data: bytes) -> int:
    crc = 0
    for byte in data:
        crc = _TABLE[((crc >> 56) ^ byte) & 0xFF] ^ ((crc << 8) & 0xFFFFFFFFFFFFFFFF)
    return crc


def message(kind: str, device: str, content: bytes, version: int = 1) -> bytes:
    """A whole message: header and body (version 2: a 12-byte extended header, no metadata)."""
    body = content
    if version == 2:
        body = struct.pack(">HHII", 12, 0, 0, 7) + content
    header = HEADER.pack(version, kind.encode(), device.encode(), 0, len(body), crc64(body))
    return header + body


def sensor(device: str, values, version: int = 1) -> bytes:
    """SENSOR: uint8 array length, uint8 status, uint64 unit, then float64 values."""
    content = struct.pack(">BBQ", len(values), 0, 0) + struct.pack(f">{len(values)}d", *values)
    return message("SENSOR", device, content, version)


def transform(device: str, depth_mm: float, angle_deg: float) -> bytes:
    """TRANSFORM: the upper 3 x 4 of the pose, column by column, float32."""
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    cols = [c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, depth_mm]
    return message("TRANSFORM", device, struct.pack(">12f", *cols))


def image(device: str, nx: int, ny: int, nz: int) -> bytes:
    """IMAGE of uint16 voxels (what a 3D Slicer user might send along): its 72-byte image header
    (version, components, scalar type 5 = uint16, endian 1 = big, coordinates 1 = RAS, size,
    the 3 x 4 matrix, sub-volume offset and size), then the voxels."""
    head = struct.pack(">HBBBB3H12f3H3H", 1, 1, 5, 1, 1, nx, ny, nz,
                       1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, nx, ny, nz)
    assert len(head) == 72
    voxels = bytes((i * 7) & 0xFF for i in range(2 * nx * ny * nz))
    return message("IMAGE", device, head + voxels)


class Client:
    """One TCP connection speaking OpenIGTLink."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=20)
        self.rx = b""

    def send(self, data: bytes):
        self.sock.sendall(data)

    def read_message(self, timeout: float = 20.0):
        """The next message (kind, device, values of a SENSOR); None when the server closed."""
        end = time.monotonic() + timeout
        while True:
            if len(self.rx) >= HEADER.size:
                version, kind, device, _, size, crc = HEADER.unpack_from(self.rx)
                if len(self.rx) >= HEADER.size + size:
                    body = self.rx[HEADER.size:HEADER.size + size]
                    self.rx = self.rx[HEADER.size + size:]
                    assert version in (1, 2)
                    assert crc64(body) == crc, "the server's CRC-64 is the specification's"
                    kind = kind.rstrip(b"\0").decode()
                    device = device.rstrip(b"\0").decode()
                    values = None
                    if kind == "SENSOR":
                        n = body[0]
                        values = struct.unpack_from(f">{n}d", body, 10)
                    return kind, device, values
            left = end - time.monotonic()
            if left <= 0:
                raise TimeoutError("no message from the server")
            self.sock.settimeout(left)
            try:
                chunk = self.sock.recv(65536)
            except ConnectionResetError:
                return None
            if not chunk:
                return None
            self.rx += chunk

    def close(self):
        self.sock.close()


# --- the server: `vcsim run --device igtl` on a straight tube ---------------------------------

ANATOMY = {"format": "vcsim-anatomy", "version": 1, "name": "tube", "coordinates": "LPS",
           "open_start": True, "access": {"segment": "tube", "distance_mm": 190},
           "segments": [{"name": "tube", "kind": "artery", "parent": None,
                         "points_mm": [[0, 0, 0], [0, 0, 100], [0, 0, 200]], "radius_mm": 2}]}
SCENARIO = {"format": "vcsim-scenario", "version": 1, "name": "device", "anatomy": "tube.json",
            "motion": {"beating": False}, "dt_ms": 0.5, "time_limit_s": 600,
            "sheath_length_mm": 10,
            "instruments": [{"name": "wire", "catalogue": "wire-014-floppy", "max_nodes": 64,
                             "tip_segment_mm": 2}],
            "input": {"type": "timeline", "file": "timeline.json"}}
TIMELINE = {"keyframes": [{"t_s": 0, "instruments": {"wire": {"translation_mm": 0,
                                                              "rotation_deg": 0}}}]}


class Server:
    """A live run; stop() ends it with SIGTERM (a clean end: metrics.json written)."""

    def __init__(self, folder: Path, address: str = "127.0.0.1"):
        vcsim = os.environ["VCSIM_CLI"]
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "tube.json").write_text(json.dumps(ANATOMY))
        (folder / "s.json").write_text(json.dumps(SCENARIO))
        (folder / "timeline.json").write_text(json.dumps(TIMELINE))
        self.folder = folder
        self.err_path = folder / "stderr.txt"
        self.err_file = open(self.err_path, "w")
        self.proc = subprocess.Popen(
            [vcsim, "run", str(folder / "s.json"), "--device", "igtl", "--port", "0", "--address",
             address, "--no-frames", "--no-report", "--quiet", "--out", str(folder / "out")],
            stdout=subprocess.DEVNULL, stderr=self.err_file)
        self.port = 0
        key = f"listening on {address}:"
        end = time.monotonic() + 180
        while time.monotonic() < end and self.proc.poll() is None:
            m = re.search(re.escape(key) + r"(\d+)", self.stderr())
            if m:
                self.port = int(m.group(1))
                break
            time.sleep(0.02)
        assert self.port > 0, self.stderr()

    def stderr(self) -> str:
        return self.err_path.read_text()

    def wait_for_log(self, text: str, timeout: float = 20.0) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if text in self.stderr():
                return True
            time.sleep(0.02)
        return text in self.stderr()

    def stop(self) -> dict:
        """Ends the run; its metrics.json's input section."""
        self.proc.send_signal(signal.SIGTERM)
        self.proc.wait(timeout=120)
        self.err_file.close()
        assert self.proc.returncode in (0, 3), self.stderr()
        return json.loads((self.folder / "out" / "metrics.json").read_text())["input"]


@pytest.fixture
def server(tmp_path):
    s = Server(tmp_path)
    yield s
    if s.proc.poll() is None:
        s.proc.kill()
        s.proc.wait()


def forces(client: Client, count: int):
    """The next `count` force messages (as many as the server sends at 200 per second)."""
    out = []
    while len(out) < count:
        m = client.read_message()
        assert m is not None, "the server closed the connection"
        if m[0] == "SENSOR" and m[1] == "force_wire":
            out.append(m[2])
    return out


# --- tests -----------------------------------------------------------------------------------

def test_crc64_is_the_specifications():
    # ECMA-182's check value (the CRC of "123456789").
    assert crc64(b"123456789") == 0x6C40DF5F0B497347


def test_a_client_drives_the_wire_and_reads_forces(server):
    c = Client(server.port)
    c.send(sensor("wire", [30.0, 0.0]))              # header version 1
    c.send(sensor("wire", [30.0, 45.0], version=2))  # version 2, OpenIGTLink 3
    c.send(transform("wire", 30.0, 90.0))
    for f in forces(c, 20):
        assert len(f) == 2 and all(v == v for v in f)  # axial force N, torque N m; finite
    c.close()
    stats = server.stop()
    assert stats["messages_accepted"] == 3
    assert stats["messages_dropped"] == 0


def test_an_oversized_image_is_skipped_and_the_connection_stays(server):
    c = Client(server.port)
    forces(c, 2)
    big = image("reference", 256, 256, 3)  # 384 KiB of voxels: over the 64 KiB read
    assert len(big) > 6 * 65536
    c.send(big + sensor("wire", [12.0, 0.0]))
    assert server.wait_for_log("skipped IMAGE message 'reference' of"), server.stderr()
    forces(c, 20)  # still connected, still sent forces
    c.send(sensor("wire", [14.0, 0.0]))
    forces(c, 4)
    c.close()
    stats = server.stop()
    assert stats["connections"] == 1
    assert stats["messages_skipped"] == 1
    assert stats["messages_accepted"] == 2  # the SENSORs after the image, the same connection


def test_a_second_client_is_refused_while_one_is_connected(server):
    a = Client(server.port)
    forces(a, 2)
    b = Client(server.port)  # the kernel completes the handshake; the server closes it
    assert b.read_message() is None, "the second client was served"
    assert server.wait_for_log("refused a connection from 127.0.0.1:"), server.stderr()
    a.send(sensor("wire", [20.0, 0.0]))
    forces(a, 10)  # the first session goes on
    a.close()
    b.close()
    stats = server.stop()
    assert stats["connections"] == 1
    assert stats["clients_refused"] == 1
    assert stats["messages_accepted"] == 1


def test_a_burst_of_connects_is_answered(server):
    # The listening socket holds a burst (ss shows a listener's backlog as its Send-Q).
    ss = subprocess.run(["ss", "-Hltn", f"sport = :{server.port}"], capture_output=True,
                        text=True, check=True).stdout.split()
    assert int(ss[2]) >= 64, ss
    a = Client(server.port)
    forces(a, 2)
    burst = [socket.create_connection(("127.0.0.1", server.port), timeout=20) for _ in range(48)]
    for s in burst:
        assert s.recv(1) == b"", "refused: closed by the server"
        s.close()
    forces(a, 4)
    a.close()
    stats = server.stop()
    assert stats["connections"] == 1
    assert stats["clients_refused"] == 48


def test_a_device_faster_than_the_drive_is_reported_once(server):
    c = Client(server.port)
    # A speed beyond the drive's 500 mm/s, as sent (then stopped at once: a few mm in).
    c.send(sensor("vel_wire", [800.0, 0.0]) + sensor("vel_wire", [0.0, 0.0]))
    assert server.wait_for_log("'wire' moves at 800 mm/s"), server.stderr()
    c.send(sensor("vel_wire", [900.0, 0.0]) + sensor("vel_wire", [0.0, 0.0]))  # not said again
    # A turn by positions: 30000 deg within the time of 10 force messages (50 ms at 200 per
    # second; seconds on a loaded machine), far beyond the drive's 1719 deg/s.
    c.send(sensor("wire", [5.0, 0.0]))
    forces(c, 10)
    c.send(sensor("wire", [5.0, 30000.0]))
    assert server.wait_for_log("'wire' turns at"), server.stderr()
    forces(c, 10)
    c.close()
    stats = server.stop()
    log = server.stderr()
    assert log.count("'wire' moves at") == 1, log
    assert log.count("'wire' turns at") == 1, log
    assert "faster than the drive follows: it follows at 500 mm/s" in log, log
    assert stats["beyond_drive"] == 2


def test_listening_beyond_loopback_is_a_warning(tmp_path):
    loop = Server(tmp_path / "loopback")
    loop.stop()
    assert "warning: listening on" not in loop.stderr(), loop.stderr()
    wide = Server(tmp_path / "any", address="0.0.0.0")
    wide.stop()
    assert "warning: listening on 0.0.0.0: any machine that can reach this one can drive the " \
           "instruments" in wide.stderr(), wide.stderr()
