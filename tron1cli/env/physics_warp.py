"""N worlds stepped together by MuJoCo Warp (``mujoco-warp``), behind BatchedPhysics' arrays.

The same surface as :class:`~tron1cli.env.physics.BatchedPhysics`: ``state`` (N, nstate)
FULLPHYSICS rows, ``traj`` (N, nsub, nstate) and ``sensordata`` (N, nsub, nsensordata) of the
last step, ``step`` / ``set_state`` / ``forward``, so observation, reward and termination code
read it unchanged. Warp computes in float32; the host arrays stay float64.

Per-env model fields the randomiser writes (Table III: mass, CoM, friction, contact softness,
gains, torque limits) are batched model fields on the device, one row per world, taken from the
host models once at construction; afterwards :meth:`WarpPhysics.write_models` writes the sampled
(k, ...) values into the rows of the worlds named in one array operation and uploads the field
once. The device rows are the truth: ``forward`` after resets runs on the host, and copies the
reset worlds' rows to their host models first.

Terrain: flat ground is a plane; a height-field terrain is one device model holding every tile of
the bank as its own height field (:func:`~tron1cli.env.scene.build_model` with ``all_tiles``),
and each world's ground geom points at its tile through the batched ``geom_dataid``: warp
shares ``hfield_data`` between worlds, so a per-world height field is not on offer. The host
models keep their own tile as on the CPU engine (sensor data after resets is computed there).

Needs the optional ``warp`` extra (``pip install -e '.[warp]'``); it runs on warp's CPU device
when no GPU is visible (slow: for development and tests), and compiles its kernels on first use
(about 90 s on 2 cores, cached by warp under ``~/.cache/warp`` afterwards).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

import mujoco
import numpy as np

from tron1cli.env.physics import STATE_SPEC, BatchedPhysics
from tron1cli.env.scene import GROUND_NAME, build_model
from tron1cli.env.terrain import TerrainBank

#: model fields the randomiser writes per env (tron1cli.env.randomization), batched per world
BATCHED_FIELDS = (
    "body_mass",
    "body_ipos",
    "geom_friction",
    "geom_solref",
    "geom_solmix",
    "actuator_gainprm",
    "actuator_biasprm",
    "actuator_forcerange",
)


def warp_device(device: str | None = None) -> str:
    """The warp device to run on: ``device`` if given, else ``cuda:0`` when warp sees a GPU and
    ``cpu`` otherwise. ImportError with the install line when mujoco-warp is missing."""
    try:
        import warp as wp

        # before warp initialises: no device banner nor per-module load lines (warp >= 1.19 reads
        # log_level, earlier versions quiet); warnings still show
        wp.config.quiet = True
        if hasattr(wp, "LOG_WARNING"):
            wp.config.log_level = wp.LOG_WARNING
        import mujoco_warp  # noqa: F401
    except ImportError as e:
        raise ImportError("the warp backend needs mujoco-warp: pip install -e '.[warp]'") from e
    if device is not None:
        return device
    return "cuda:0" if wp.get_cuda_device_count() > 0 else "cpu"


class WarpPhysics(BatchedPhysics):
    """Batched physics over ``len(models)`` worlds on a warp device.

    Args:
        models: one MjModel per env (as BatchedPhysics); their values of :data:`BATCHED_FIELDS`
            at construction are the worlds' first device rows, edited later by
            :meth:`write_models`.
        nsub: physics substeps per :meth:`step`.
        device: warp device (``cpu``, ``cuda:0``); default as :func:`warp_device`.
        bank: the terrain bank the models' height field takes its tiles from (needed when they
            have one); the worlds start on tile 0 until :meth:`set_tiles`.
        graph: record a step's substeps once, here, as a graph and replay it every step (one
            launch a step instead of hundreds from Python); False launches each kernel every
            step, and so does a recording that fails (one ``warning:`` line on stderr, the
            reason in :attr:`graph_error`).
    """

    def __init__(
        self,
        models: Sequence[mujoco.MjModel],
        nsub: int,
        device: str | None = None,
        bank: TerrainBank | None = None,
        graph: bool = True,
    ) -> None:
        terrain = bool(models) and models[0].nhfield > 0
        if terrain and bank is None:
            raise ValueError("the warp backend needs the terrain bank of a height-field model")
        self.device = warp_device(device)
        super().__init__(models, nsub, nthread=1)  # host arrays, and mj_forward after resets
        import mujoco_warp as mjw
        import warp as wp

        m0 = self.models[0]
        dev_model = build_model(m0.opt.timestep, bank, all_tiles=True) if terrain else m0
        if (dev_model.nbody, dev_model.ngeom, dev_model.nu) != (m0.nbody, m0.ngeom, m0.nu):
            raise ValueError("the env's models are not the robot of build_model: cannot lay out tiles")
        batched = BATCHED_FIELDS + (("geom_dataid",) if terrain else ())
        self._wp, self._mjw = wp, mjw
        with wp.ScopedDevice(self.device):
            self._m = mjw.put_model(dev_model, batch_sizes={f: self.n for f in batched})
            self._d = mjw.make_data(dev_model, nworld=self.n)
            self._state_dev = wp.zeros((self.n, self.nstate), dtype=wp.float32)
        # host copies of the batched device rows (no read-back): the worlds' own models' values
        # once here, then write_models edits rows and uploads the field
        self._mirror = {f: getattr(self._m, f).numpy() for f in batched}
        for name in BATCHED_FIELDS:
            rows = self._mirror[name]
            rows[:] = np.stack([getattr(m, name) for m in self.models]).reshape(rows.shape)
            getattr(self._m, name).assign(rows)
        self._ground = dev_model.geom(GROUND_NAME).id
        # one step's inputs and outputs on the device, substep first: uploaded and read back once
        # a step, so the substeps are device work only (one graph launch where captured)
        with wp.ScopedDevice(self.device):
            self._ctrl_dev = wp.zeros((nsub, self.n, self.nu), dtype=wp.float32)
            self._xfrc_dev = wp.zeros((nsub, self.n, self.nbody), dtype=self._d.xfrc_applied.dtype)
            self._traj_dev = wp.zeros((nsub, self.n, self.nstate), dtype=wp.float32)
            self._sens_dev = wp.zeros((nsub, self.n, self.nsensordata), dtype=wp.float32)
        self._graph = None
        #: why the step is not recorded (it launches each kernel instead), or None
        self.graph_error: str | None = None
        if graph:
            try:
                self._graph = self._capture()
            except Exception as e:  # e.g. a mujoco-warp whose step reads back from the device
                first = str(e).strip().splitlines()
                self.graph_error = f"{type(e).__name__}: {first[0]}" if first else type(e).__name__
                sys.stderr.write(
                    f"warning: warp could not record a physics step ({self.graph_error}); "
                    "launching each kernel instead, which is slower\n"
                )

    def write_models(self, ids: np.ndarray, name: str, index: tuple, values: np.ndarray) -> None:
        """As :meth:`BatchedPhysics.write_models`, on the device rows of the worlds ``ids`` (a field
        of :data:`BATCHED_FIELDS`): one array write and one upload, no loop over worlds. The host
        models are left alone; :meth:`forward` copies a world's rows to its host model when it
        needs them (the restitution gate writes hundreds of worlds a step, resets a few)."""
        if name not in BATCHED_FIELDS:
            raise ValueError(f"{name} is not a batched field of the warp model")
        ids = np.asarray(ids, dtype=np.int64)
        if ids.size == 0:
            return
        rows = self._mirror[name]
        part = rows[ids]
        target = part[(slice(None), *index)]
        v = np.asarray(values)
        part[(slice(None), *index)] = v.reshape(len(ids), *(1,) * (target.ndim - v.ndim), *v.shape[1:])
        rows[ids] = part
        getattr(self._m, name).assign(rows)

    def forward(self, ids: np.ndarray, ctrl: np.ndarray) -> None:
        """As :meth:`BatchedPhysics.forward` (on the host), after the worlds' own device rows of
        :data:`BATCHED_FIELDS` are copied to their host models."""
        for i in np.asarray(ids):
            m = self.models[i]
            for name in BATCHED_FIELDS:
                field = getattr(m, name)
                field[...] = self._mirror[name][i].reshape(field.shape)
        super().forward(ids, ctrl)

    def set_tiles(self, ids: np.ndarray, bank: TerrainBank, tiles: np.ndarray) -> None:
        """Put the worlds of envs ``ids`` on tiles ``tiles`` (k,): their ground geom points at the
        tile's height field on the device; the host models take the tile as on the CPU engine."""
        super().set_tiles(ids, bank, tiles)
        rows = self._mirror["geom_dataid"]
        rows[np.asarray(ids), self._ground] = np.asarray(tiles)
        self._m.geom_dataid.assign(rows)

    def rollout(self) -> None:
        """Step every world ``nsub`` times from ``state`` under ``control``; as BatchedPhysics,
        with no solver warm start carried between calls. Three uploads (state, controls, wrenches)
        and two read-backs (states and sensor data of every substep) a call."""
        wp = self._wp
        c = self.control.transpose(1, 0, 2)  # (nsub, N, ncontrol)
        t0 = self.state[:, 0].copy()
        with wp.ScopedDevice(self.device):
            self._state_dev.assign(self.state.astype(np.float32))
            self._ctrl_dev.assign(np.ascontiguousarray(c[..., : self.nu], dtype=np.float32))
            xfrc = c[..., self.nu :].reshape(self.nsub, self.n, self.nbody, 6)
            self._xfrc_dev.assign(np.ascontiguousarray(xfrc, dtype=np.float32))
            if self._graph is not None:
                wp.capture_launch(self._graph)
            else:
                self._substeps()
            self.traj[:] = self._traj_dev.numpy().transpose(1, 0, 2)
            self.sensordata[:] = self._sens_dev.numpy().transpose(1, 0, 2)
        # time in float64 as on the CPU engine: the device's float32 clock, re-uploaded every step,
        # drifts by 4e-5 s after 4 s of episode, which the env core's check for MuJoCo's own
        # resets (time restarting) took for a diverged world; mujoco-warp never restarts a world
        # (a diverged one shows as NaN in the other columns, which stay the device's)
        self.traj[:, :, 0] = t0[:, None] + self.dt * np.arange(1, self.nsub + 1)
        self.state[:] = self.traj[:, -1]

    def _substeps(self) -> None:
        """The device work of one :meth:`rollout`: state in, ``nsub`` steps, each substep's state
        and sensor data out. Device arrays only, the same ones every call (what a graph needs)."""
        wp, mjw, m, d = self._wp, self._mjw, self._m, self._d
        mjw.set_state(m, d, self._state_dev, int(STATE_SPEC))
        d.qacc_warmstart.zero_()
        for s in range(self.nsub):
            wp.copy(d.ctrl, self._ctrl_dev[s])
            wp.copy(d.xfrc_applied, self._xfrc_dev[s])
            mjw.step(m, d)
            mjw.get_state(m, d, self._traj_dev[s], int(STATE_SPEC))
            wp.copy(self._sens_dev[s], d.sensordata)

    def _capture(self):
        """:meth:`_substeps` recorded as one graph (a CUDA graph on a GPU; warp's replayed
        operation list on its CPU device). It holds the device arrays' addresses: the model
        fields are written in place (``assign``), never replaced, so it stays valid."""
        wp = self._wp
        with wp.ScopedDevice(self.device), wp.ScopedCapture(device=self.device) as capture:
            self._substeps()
        return capture.graph

    def close(self) -> None:
        """Release the device arrays (the host side holds nothing to shut down)."""
        super().close()
        self._m = self._d = self._state_dev = self._graph = None
        self._ctrl_dev = self._xfrc_dev = self._traj_dev = self._sens_dev = None
