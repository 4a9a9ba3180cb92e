"""Depth sources for perceptive policies on deploy-robot: whatever fills the contract's depth input.

:class:`DepthSource` is the interface :class:`tron1cli.deploy.robot.RobotController` reads:
``newest()`` gives the newest (rows, cols) float32 z-depth image in metres (0 = no return), or None
before the first frame; ``age_s()`` the seconds since it arrived (inf before the first).
:class:`RealSenseDepth` fills it on the robot from a RealSense D435i through ``pyrealsense2``,
in its own thread at the contract's depth rate (30 Hz): it starts the camera, takes each depth
frame, crops it to the contract's field of view, reduces it to the contract's size, converts it to
metres and blanks what lies outside the contract's range. It is thin on purpose and untested here
(no camera on this machine). :class:`tron1cli.deploy.depth_link.UdpDepth` takes frames from
another process (sim-robot's renderer, or any camera process).
"""

from __future__ import annotations

import threading
import time
from typing import Protocol

import numpy as np

from tron1cli.errors import Tron1Error


class DepthSource(Protocol):
    def start(self) -> None: ...

    def newest(self) -> np.ndarray | None: ...

    def age_s(self) -> float: ...

    def close(self) -> None: ...


class NewestFrame:
    """The newest frame of a depth source and when it arrived (monotonic s), guarded by a lock:
    the source's reader thread calls :meth:`_put`, the controller :meth:`newest` and :meth:`age_s`."""

    def __init__(self) -> None:
        self._frame: np.ndarray | None = None
        self._t_arrival = -np.inf
        self._lock = threading.Lock()

    def _put(self, image: np.ndarray) -> None:
        with self._lock:
            self._frame, self._t_arrival = image, time.monotonic()

    def newest(self) -> np.ndarray | None:
        with self._lock:
            return self._frame

    def age_s(self) -> float:
        with self._lock:
            return time.monotonic() - self._t_arrival


def crop_resize(
    depth_m: np.ndarray, fov_have: tuple[float, float], fov_want: tuple[float, float], rows: int, cols: int
) -> np.ndarray:
    """Centre-crop a (H, W) depth image of field of view ``fov_have`` (deg, horizontal, vertical)
    to ``fov_want`` and reduce it to (rows, cols) by nearest sampling (no blending across edges)."""
    h, w = depth_m.shape
    fx = np.tan(np.radians(min(fov_want[0], fov_have[0])) / 2) / np.tan(np.radians(fov_have[0]) / 2)
    fy = np.tan(np.radians(min(fov_want[1], fov_have[1])) / 2) / np.tan(np.radians(fov_have[1]) / 2)
    cw, ch = max(1, int(round(w * fx))), max(1, int(round(h * fy)))
    x0, y0 = (w - cw) // 2, (h - ch) // 2
    ys = y0 + ((np.arange(rows) + 0.5) * ch / rows).astype(int)
    xs = x0 + ((np.arange(cols) + 0.5) * cw / cols).astype(int)
    return depth_m[np.ix_(ys, xs)].astype(np.float32)


class RealSenseDepth(NewestFrame):
    """A D435i's depth stream as the contract's image (``contract["depth"]``), 30 Hz in its own
    thread. Untested here: no camera on this machine."""

    def __init__(self, depth_contract: dict, width: int = 848, height: int = 480, fps: int = 30) -> None:
        try:
            import pyrealsense2 as rs
        except ImportError:
            raise Tron1Error("--depth realsense needs pyrealsense2 (pip install pyrealsense2)") from None
        super().__init__()
        self.rs = rs
        self.rows, self.cols = int(depth_contract["rows"]), int(depth_contract["cols"])
        self.near, self.far = (float(x) for x in depth_contract["range_m"])
        self.fov_want = tuple(float(x) for x in depth_contract["fov_deg"])
        self.size, self.fps = (width, height), fps
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="tron1-realsense", daemon=True)
        self.pipe = None

    def start(self) -> None:
        rs = self.rs
        cfg = rs.config()
        cfg.enable_stream(rs.stream.depth, self.size[0], self.size[1], rs.format.z16, self.fps)
        self.pipe = rs.pipeline()
        profile = self.pipe.start(cfg)
        self.scale = profile.get_device().first_depth_sensor().get_depth_scale()  # m per unit
        intr = profile.get_stream(rs.stream.depth).as_video_stream_profile().get_intrinsics()
        self.fov_have = (
            float(np.degrees(2 * np.arctan(intr.width / (2 * intr.fx)))),
            float(np.degrees(2 * np.arctan(intr.height / (2 * intr.fy)))),
        )
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            frames = self.pipe.wait_for_frames()
            d = frames.get_depth_frame()
            if not d:
                continue
            img = np.asanyarray(d.get_data()).astype(np.float32) * self.scale
            img = crop_resize(img, self.fov_have, self.fov_want, self.rows, self.cols)
            img[(img < self.near) | (img > self.far)] = 0.0
            self._put(img)

    def close(self) -> None:
        self._stop.set()
        if self.pipe is not None:
            self.pipe.stop()
