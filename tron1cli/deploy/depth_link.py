"""A depth camera over UDP: how ``sim-robot`` hands its rendered frames to ``deploy-robot``.

LimX's SDK carries joint state, IMU and commands but no images, so a simulated robot needs a side
channel for its camera, as a camera driver on another computer would. One datagram holds one frame
as a RealSense delivers it: z-depth in millimetres, uint16, 0 = no return, after a 16-byte header

    magic b"T1D1", seq (uint32), rows (uint16), cols (uint16), capture time (float32, sender's
    clock, s), all little-endian.

An 80 x 60 frame is 9,616 bytes, one datagram on any link. :class:`UdpDepth` is the receiving
:class:`tron1cli.deploy.depth_source.DepthSource`: a thread keeps the newest frame of the expected
size (older or foreign datagrams are counted and dropped); deploy-robot trips to damping when
frames stop (``RobotConfig.depth_timeout_s``).
"""

from __future__ import annotations

import socket
import struct
import threading

import numpy as np

from tron1cli.deploy.depth_source import NewestFrame
from tron1cli.errors import UsageError

MAGIC = b"T1D1"
HEADER = struct.Struct("<4sIHHf")
DEFAULT_PORT = 47017


def parse_address(text: str, default_host: str = "127.0.0.1") -> tuple[str, int]:
    """``HOST:PORT``, ``:PORT`` or ``PORT`` -> (host, port); UsageError otherwise."""
    host, _, port = text.rpartition(":")
    try:
        p = int(port)
    except ValueError:
        raise UsageError(f"'{text}' is not an address HOST:PORT or a port") from None
    if not 0 < p < 65536:
        raise UsageError(f"port {p} outside 1..65535")
    return host or default_host, p


def encode(image_m: np.ndarray, seq: int, t_capture: float) -> bytes:
    """One datagram of a (rows, cols) depth image in metres (0 or non-finite = no return)."""
    img = np.nan_to_num(np.asarray(image_m, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    mm = np.clip(np.rint(img * 1000.0), 0, 65535).astype("<u2")
    rows, cols = mm.shape
    return HEADER.pack(MAGIC, seq & 0xFFFFFFFF, rows, cols, t_capture) + mm.tobytes()


def decode(packet: bytes) -> tuple[int, float, np.ndarray] | None:
    """(seq, capture time, (rows, cols) float32 metres) of a datagram; None if it is not one."""
    if len(packet) < HEADER.size:
        return None
    magic, seq, rows, cols, t = HEADER.unpack_from(packet)
    if magic != MAGIC or len(packet) != HEADER.size + 2 * rows * cols:
        return None
    mm = np.frombuffer(packet, dtype="<u2", offset=HEADER.size).reshape(rows, cols)
    return seq, float(t), mm.astype(np.float32) / 1000.0


class DepthSender:
    """Sends frames to ``(host, port)``; a missing receiver costs nothing (UDP)."""

    def __init__(self, host: str, port: int) -> None:
        self.addr = (host, port)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sent = 0

    def send(self, image_m: np.ndarray, seq: int, t_capture: float) -> None:
        try:
            self.sock.sendto(encode(image_m, seq, t_capture), self.addr)
            self.sent += 1
        except OSError:  # no route, receiver gone: a camera does not stop for that
            pass

    def close(self) -> None:
        self.sock.close()


class UdpDepth(NewestFrame):
    """Frames from a :class:`DepthSender` on ``port`` (all interfaces), for deploy-robot.

    rows, cols: the contract's image size; a frame of another size is dropped and counted in
    ``foreign``, as is any datagram that is not a frame. ``age_s()``: seconds since the newest
    frame arrived (inf before the first)."""

    def __init__(self, port: int, rows: int, cols: int, host: str = "0.0.0.0") -> None:
        super().__init__()
        self.rows, self.cols = int(rows), int(cols)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.sock.bind((host, port))
        except OSError as e:
            self.sock.close()
            raise UsageError(f"cannot listen for depth frames on UDP port {port} ({e.strerror})") from None
        self.sock.settimeout(0.05)
        self.received = 0
        self.foreign = 0
        self.late = 0
        self._seq = -1  # the newest frame's; only the receiver thread reads or writes it
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="tron1-udp-depth", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                packet = self.sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return  # closed
            frame = decode(packet)
            if frame is None or frame[2].shape != (self.rows, self.cols):
                self.foreign += 1
                continue
            seq, _, image = frame
            if self._seq - 100 < seq <= self._seq:  # reordered: keep the newer (far back: a restart)
                self.late += 1
                continue
            self._seq = seq
            self._put(image)
            self.received += 1

    def close(self) -> None:
        self._stop.set()
        self.sock.close()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)
