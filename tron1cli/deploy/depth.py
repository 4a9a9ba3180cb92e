"""The depth camera pipeline of deploy-sim: frames rendered in their own thread, at their own rate.

The control loop (the caller's thread) captures a frame every 1/depth_hz of simulation time: it
snapshots the camera pose and hands it over (:meth:`DepthPipeline.capture`). The render thread
ray-marches the terrain (:func:`tron1cli.env.sensors.render_depth`, a numba kernel that releases
the GIL) and adds the sensor noise, while the control loop keeps stepping physics and the policy.
At every policy step the loop takes the newest frame that is ready (:meth:`DepthPipeline.newest`).

Time. Simulation time is the clock. A frame captured at ``t_capture`` is ready at
``t_ready = t_start + render_s + latency_s``: ``t_start`` is when the renderer got to it (after
its previous frame), ``render_s`` the render's measured wall-clock duration and ``latency_s`` the
added latency (transport, driver). The loop uses a frame only once its ``t_ready`` has passed.
When the simulation runs faster than real time it can reach ``t`` before the renderer has
finished a frame that would be ready by then; only then does it wait for the renderer. So the
frame a policy step sees is the one the robot's computer would have had, both when paced to the
wall clock and when not, and the render still overlaps physics and inference in wall time.

When the renderer gets free (in simulation time) it takes the newest frame captured by then;
older frames still waiting are dropped, as a camera driver drops frames its reader is too slow
for.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from dataclasses import dataclass

import numba
import numpy as np

from tron1cli.env import sensors


@dataclass(frozen=True)
class DepthFrame:
    """One rendered frame.

    image: (rows, cols) float32 z-depth in m (0 = no return); seq: capture number (0, 1, ...);
    t_capture, t_ready: simulation time (s) of the camera pose, and from which the frame may be
    used; render_ms: wall-clock time of ray march plus noise (ms).
    """

    image: np.ndarray
    seq: int
    t_capture: float
    t_ready: float
    render_ms: float


@dataclass
class _Request:
    seq: int
    t_capture: float
    cam_pos: np.ndarray  # (1, 3) world, m
    cam_rot: np.ndarray  # (1, 3, 3) world, MuJoCo camera axes
    tile: np.ndarray  # (1,) tile index
    ray_scale: np.ndarray | None = None  # (1,) randomised field of view (see Tron1Env.depth_ray_scale)
    v_start: float = math.nan  # simulation time at which the renderer started it
    wall_start: float = math.nan  # perf_counter() at that moment


class DepthPipeline:
    """Renders env 0's depth camera in a background thread; see the module docstring.

    env: a :class:`tron1cli.env.core.Tron1Env` with perception (its own depth rendering switched
    off with ``depth_from = num_envs``); latency_s: added latency (s); noise: D435i noise and
    holes; seed: seed of the noise; numba_lock: a lock held around every render (and by the
    caller around its own numba calls) where numba's threading layer is not thread-safe;
    render_threads: numba threads of the ray march (1: the render thread alone, on its own core).
    """

    def __init__(
        self,
        env,
        latency_s: float = 0.0,
        noise: bool = True,
        seed: int = 0,
        numba_lock: threading.Lock | None = None,
        render_threads: int = 1,
    ) -> None:
        if env.camera is None:
            raise ValueError("the env has no depth camera (perception is off)")
        self.env = env
        self.camera = env.camera
        self.latency_s = float(latency_s)
        self.noise = noise
        self.render_threads = render_threads
        self._heights = env.bank.heights
        self._res = env.bank.res
        self._maps = sensors.depth_max_maps(self._heights)
        self._rng = np.random.default_rng([seed, 30])  # the thread's own stream: env.rng is not shared
        self._lock = numba_lock or contextlib.nullcontext()
        self._cond = threading.Condition()
        self._queue: list[_Request] = []  # captured, waiting for the renderer, oldest first
        self._busy: _Request | None = None  # being rendered
        self._ready: list[DepthFrame] = []  # rendered, oldest first
        self._v_free = -math.inf  # simulation time at which the renderer finished its last frame
        self._seq = 0
        self._stop = False
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="tron1-depth", daemon=True)
        # figures
        self.rendered = 0
        self.dropped = 0
        self.render_ms: list[float] = []
        self.capture_times: list[float] = []
        self.render_thread_ids: set[int] = set()
        self.busy_s = 0.0  # wall time the renderer spent on frames
        self.wait_s = 0.0  # wall time the control loop spent waiting for the renderer

    # -- control loop side ------------------------------------------------------------------
    def start(self) -> None:
        self._thread.start()

    def capture(self, t: float) -> None:
        """Snapshot env 0's camera pose at simulation time ``t`` (s) and queue it for rendering."""
        ids = np.zeros(1, dtype=np.int64)
        pos, rot = self.env.camera_pose(ids)
        req = _Request(
            self._seq,
            float(t),
            pos.copy(),
            rot.copy(),
            self.env.curriculum.tile[ids].copy(),
            ray_scale=self.env.depth_ray_scale(ids),
        )
        self._seq += 1
        self.capture_times.append(float(t))
        with self._cond:
            self._queue.append(req)
            self._cond.notify_all()

    def first(self, timeout_s: float = 60.0) -> DepthFrame:
        """Block until the first frame is rendered and return it (the controller starts when the
        camera streams)."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._ready or self._error, timeout=timeout_s):
                raise RuntimeError(f"no depth frame within {timeout_s:g} s")
            self._raise()
            return self._ready[-1]

    def newest(self, t: float) -> DepthFrame | None:
        """The newest frame ready at simulation time ``t`` (s), or None when none is; waits for the
        renderer only where a frame it is still working on would be ready by ``t``."""
        with self._cond:
            while True:
                self._raise()
                lb = self._ready_lower_bound()
                if lb is None or lb >= t:  # render time > 0: a frame is never ready at its bound
                    break
                t0 = time.perf_counter()
                # a busy frame's bound grows with wall time: after (t - lb) s it is past t
                self._cond.wait(timeout=(t - lb) + 1e-4 if self._busy is not None else 0.05)
                self.wait_s += time.perf_counter() - t0
            usable = [f for f in self._ready if f.t_ready <= t]
            if not usable:
                return None
            frame = usable[-1]
            self._ready = [f for f in self._ready if f.seq >= frame.seq]
            return frame

    def close(self) -> None:
        """Stop the render thread (frames still queued are dropped)."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._thread.is_alive():
            self._thread.join(timeout=10.0)

    def _ready_lower_bound(self) -> float | None:
        """Simulation time the oldest unfinished frame's ``t_ready`` exceeds (lock held)."""
        r = self._busy
        if r is not None:
            return r.v_start + (time.perf_counter() - r.wall_start) + self.latency_s
        if self._queue:
            return max(self._queue[0].t_capture, self._v_free) + self.latency_s
        return None

    def _raise(self) -> None:
        if self._error is not None:
            raise RuntimeError(f"depth render thread failed: {self._error!r}") from self._error

    # -- render thread ----------------------------------------------------------------------
    def _run(self) -> None:
        self.render_thread_ids.add(threading.get_ident())
        try:
            numba.set_num_threads(min(self.render_threads, numba.config.NUMBA_NUM_THREADS))
            while True:
                with self._cond:
                    self._cond.wait_for(lambda: self._queue or self._stop)
                    if self._stop:
                        return
                    # the newest frame captured by the time the renderer became free
                    while len(self._queue) > 1 and self._queue[1].t_capture <= self._v_free:
                        self._queue.pop(0)
                        self.dropped += 1
                    req = self._queue.pop(0)
                    req.v_start = max(req.t_capture, self._v_free)
                    req.wall_start = time.perf_counter()
                    self._busy = req
                    self._cond.notify_all()  # a waiting control loop re-checks the frame's bound
                image = self._render(req)
                render_s = time.perf_counter() - req.wall_start
                with self._cond:
                    v_end = req.v_start + render_s
                    self._v_free = v_end
                    self._ready.append(
                        DepthFrame(image, req.seq, req.t_capture, v_end + self.latency_s, 1e3 * render_s)
                    )
                    self._busy = None
                    self.rendered += 1
                    self.render_ms.append(1e3 * render_s)
                    self.busy_s += render_s
                    self._cond.notify_all()
        except BaseException as e:  # handed to the control loop, which raises it
            with self._cond:
                self._error = e
                self._busy = None
                self._cond.notify_all()

    def _render(self, req: _Request) -> np.ndarray:
        with self._lock:
            img = sensors.render_depth(
                self._heights,
                req.tile,
                req.cam_pos,
                req.cam_rot,
                self.camera,
                self._res,
                max_maps=self._maps,
                ray_scale=req.ray_scale,
            )
            if self.noise:
                img = sensors.add_depth_noise(img, self.camera, self._rng)
        return img[0]
