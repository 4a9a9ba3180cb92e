"""N worlds stepped together by MuJoCo Warp (``mujoco-warp``), behind BatchedPhysics' arrays.

The same surface as :class:`~tron1cli.env.physics.BatchedPhysics`: ``state`` (N, nstate)
FULLPHYSICS rows, ``traj`` (N, nsub, nstate) and ``sensordata`` (N, nsub, nsensordata) of the
last step, ``step`` / ``set_state`` / ``forward``, so observation, reward and termination code
read it unchanged. Warp computes in float32; the host arrays stay float64.

Per-env model fields the randomiser writes (Table III: mass, CoM, friction, contact softness,
gains, torque limits) are batched model fields on the device, one row per world; after the host
models change, :meth:`WarpPhysics.sync` copies the changed worlds' rows.

Terrain: flat ground (a plane) only. Warp shares ``hfield_data`` between worlds; its batched
``geom_dataid`` could point each world's ground at its own tile of one model holding them all,
but that layout did not follow the CPU engine on stairs when tried (README, physics backends).

Needs the optional ``warp`` extra (``pip install -e '.[warp]'``); it runs on warp's CPU device
when no GPU is visible (slow: for development and tests), and compiles its kernels on first use
(about 90 s on 2 cores, cached by warp under ``~/.cache/warp`` afterwards).
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from tron1cli.env.physics import STATE_SPEC, BatchedPhysics

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

        wp.config.quiet = True  # before mujoco_warp initialises warp: no device banner
        import mujoco_warp  # noqa: F401
    except ImportError as e:
        raise ImportError("the warp backend needs mujoco-warp: pip install -e '.[warp]'") from e
    if device is not None:
        return device
    return "cuda:0" if wp.get_cuda_device_count() > 0 else "cpu"


class WarpPhysics(BatchedPhysics):
    """Batched physics over ``len(models)`` worlds on a warp device.

    Args:
        models: one MjModel per env (as BatchedPhysics; the host copies the env core and the
            randomiser edit; :meth:`sync` carries their edits to the device).
        nsub: physics substeps per :meth:`step`.
        device: warp device (``cpu``, ``cuda:0``); default as :func:`warp_device`.
    """

    def __init__(
        self,
        models: Sequence[mujoco.MjModel],
        nsub: int,
        device: str | None = None,
    ) -> None:
        if models and models[0].nhfield:
            raise ValueError("the warp backend runs on flat ground only for now (--terrain flat)")
        self.device = warp_device(device)
        super().__init__(models, nsub, nthread=1)  # host arrays, and mj_forward after resets
        import mujoco_warp as mjw
        import warp as wp

        m0 = self.models[0]
        self._wp, self._mjw = wp, mjw
        with wp.ScopedDevice(self.device):
            self._m = mjw.put_model(m0, batch_sizes={f: self.n for f in BATCHED_FIELDS})
            self._d = mjw.make_data(m0, nworld=self.n)
            self._state_dev = wp.zeros((self.n, self.nstate), dtype=wp.float32)
        # host copies of the batched device rows: sync writes rows here and uploads the field
        self._mirror = {f: getattr(self._m, f).numpy() for f in BATCHED_FIELDS}
        self._xfrc = np.zeros((self.n, self.nbody, 6), dtype=np.float32)
        self.sync(np.arange(self.n))

    def sync(self, ids: np.ndarray) -> None:
        """Copy the batched fields (:data:`BATCHED_FIELDS`) of envs ``ids`` from their host
        models to the device, through host mirrors of the device rows (no read-back)."""
        ids = np.asarray(ids, dtype=np.int64)
        if ids.size == 0:
            return
        for name, rows in self._mirror.items():
            rows[ids] = np.stack([getattr(self.models[i], name) for i in ids]).reshape(
                (len(ids), *rows.shape[1:])
            )
            getattr(self._m, name).assign(rows)

    def rollout(self) -> None:
        """Step every world ``nsub`` times from ``state`` under ``control``; as BatchedPhysics,
        with no solver warm start carried between calls."""
        wp, mjw, m, d = self._wp, self._mjw, self._m, self._d
        nu, a = self.nu, self.nu
        with wp.ScopedDevice(self.device):
            self._state_dev.assign(self.state.astype(np.float32))
            mjw.set_state(m, d, self._state_dev, int(STATE_SPEC))
            d.qacc_warmstart.zero_()
            for s in range(self.nsub):
                d.ctrl.assign(self.control[:, s, :nu].astype(np.float32))
                self._xfrc[:] = self.control[:, s, a:].reshape(self.n, self.nbody, 6)
                d.xfrc_applied.assign(self._xfrc)
                mjw.step(m, d)
                mjw.get_state(m, d, self._state_dev, int(STATE_SPEC))
                self.traj[:, s] = self._state_dev.numpy()
                self.sensordata[:, s] = d.sensordata.numpy()
        self.state[:] = self.traj[:, -1]

    def close(self) -> None:
        """Release the device arrays (the host side holds nothing to shut down)."""
        super().close()
        self._m = self._d = self._state_dev = None
