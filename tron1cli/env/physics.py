"""N MuJoCo worlds stepped together by ``mujoco.rollout`` in a persistent thread pool.

This is the only module that steps MuJoCo. Everything it hands back is a plain array with the
env dimension first (state rows, per-substep sensor data), so a GPU backend could fill the same
arrays later without touching observation, reward or termination code; MuJoCo Warp does
(:mod:`tron1cli.env.physics_warp`, chosen by :func:`make_physics`).
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
from mujoco import rollout

from tron1cli.env.scene import set_tile
from tron1cli.env.terrain import TerrainBank

#: physics engines behind the env core: MuJoCo's C engine on the CPU; MuJoCo Warp (a GPU when warp
#: sees one, else warp's CPU device). A setting of the machine, like the
#: learner's device: runs, checkpoints and policies do not record it.
BACKENDS = ("mujoco", "warp")

STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS
CONTROL_SPEC = mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_XFRC_APPLIED


class BatchedPhysics:
    """Batched physics over ``len(models)`` worlds of one size signature.

    Args:
        models: one MjModel per env (the same object may repeat; models must share sizes).
        nsub: physics substeps per call of :meth:`step` (the policy decimation).
        nthread: worker threads of the rollout pool.
    """

    #: where the physics runs (a warp device for :class:`~tron1cli.env.physics_warp.WarpPhysics`)
    device: str = "cpu"

    def __init__(self, models: Sequence[mujoco.MjModel], nsub: int, nthread: int = 2) -> None:
        if not models:
            raise ValueError("BatchedPhysics needs at least one model")
        self.models = list(models)
        self.n = len(self.models)
        self.nsub = nsub
        m = self.models[0]
        self.nq, self.nv, self.nu, self.nbody = m.nq, m.nv, m.nu, m.nbody
        self.dt = float(m.opt.timestep)
        self.nstate = mujoco.mj_stateSize(m, STATE_SPEC)
        self.ncontrol = mujoco.mj_stateSize(m, CONTROL_SPEC)
        self.nsensordata = m.nsensordata
        self._datas = [mujoco.MjData(m) for _ in range(max(1, nthread))]
        self._scratch = mujoco.MjData(m)
        self._pool = rollout.Rollout(nthread=max(1, nthread))
        self.state = np.zeros((self.n, self.nstate))
        self.traj = np.zeros((self.n, nsub, self.nstate))
        self.sensordata = np.zeros((self.n, nsub, self.nsensordata))
        self.control = np.zeros((self.n, nsub, self.ncontrol))
        self._warmstart = np.zeros((self.n, self.nv))
        # Slices of a FULLPHYSICS state row: time, qpos, qvel, act, ...
        self.qpos_slice = slice(1, 1 + self.nq)
        self.qvel_slice = slice(1 + self.nq, 1 + self.nq + self.nv)
        self.sensor_slices = {
            m.sensor(i).name: slice(int(m.sensor_adr[i]), int(m.sensor_adr[i] + m.sensor_dim[i]))
            for i in range(m.nsensor)
        }

    # -- access -----------------------------------------------------------------------------
    @property
    def time(self) -> np.ndarray:
        """Simulation time of every env (N,), s."""
        return self.state[:, 0]

    @property
    def qpos(self) -> np.ndarray:
        """Generalised positions at the end of the last step (N, nq)."""
        return self.state[:, self.qpos_slice]

    @property
    def qvel(self) -> np.ndarray:
        """Generalised velocities at the end of the last step (N, nv)."""
        return self.state[:, self.qvel_slice]

    def sensor(self, name: str, substep: int = -1) -> np.ndarray:
        """Sensor ``name`` of every env at ``substep`` of the last step, (N, dim)."""
        return self.sensordata[:, substep, self.sensor_slices[name]]

    # -- stepping ---------------------------------------------------------------------------
    def step(self, ctrl: np.ndarray, xfrc: np.ndarray | None = None, xfrc_body: int = 1) -> None:
        """Advance every env by ``nsub`` substeps.

        Args:
            ctrl: actuator controls per substep (N, nsub, nu); for position actuators the joint
                targets (rad).
            xfrc: optional world-frame wrench on body ``xfrc_body`` (N, 6): force (N), torque (N m),
                held over the whole step.
        """
        self.control[:, :, : self.nu] = ctrl
        if xfrc is not None:
            a = self.nu + 6 * xfrc_body
            self.control[:, :, a : a + 6] = xfrc[:, None, :]
        self.rollout()

    def rollout(self) -> None:
        """Run rollout from ``state`` with the prepared controls; the end state replaces ``state``."""
        self._warmstart[:] = 0.0  # no solver state carried between calls: results are reproducible
        self._pool.rollout(
            self.models,
            self._datas,
            self.state,
            self.control,
            control_spec=CONTROL_SPEC,
            skip_checks=True,
            nstep=self.nsub,
            initial_warmstart=self._warmstart,
            state=self.traj,
            sensordata=self.sensordata,
        )
        self.state[:] = self.traj[:, -1]

    def write_models(self, ids: np.ndarray, name: str, index: tuple, values: np.ndarray) -> None:
        """Set ``model.<name>[index]`` of envs ``ids`` (k,) to ``values`` (k, ...), row j for env
        ``ids[j]`` (each row broadcast to the indexed part). The randomiser's one way into the
        engine: here it writes the host models, which rollout reads."""
        for i, v in zip(np.asarray(ids), values, strict=True):
            getattr(self.models[i], name)[index] = v

    def set_tiles(self, ids: np.ndarray, bank: TerrainBank, tiles: np.ndarray) -> None:
        """Put the worlds of envs ``ids`` on tiles ``tiles`` (k,) of ``bank``: their models' height
        fields are rewritten."""
        for i, tile in zip(np.asarray(ids), np.asarray(tiles), strict=True):
            set_tile(self.models[i], bank, int(tile))

    def set_state(self, ids: np.ndarray, qpos: np.ndarray, qvel: np.ndarray) -> None:
        """Overwrite the state of envs ``ids``: time 0, given qpos (k, nq) and qvel (k, nv)."""
        self.state[ids] = 0.0
        self.state[ids, self.qpos_slice] = qpos
        self.state[ids, self.qvel_slice] = qvel

    def forward(self, ids: np.ndarray, ctrl: np.ndarray) -> None:
        """Recompute the sensor data of envs ``ids`` at their current state and controls ``ctrl``
        (k, nu), after a reset.

        Loops over the given envs only (a few per step), filling every substep row so that the
        last-substep and history readers both see the reset state.
        """
        d = self._scratch
        for k, i in enumerate(np.asarray(ids)):
            m = self.models[i]
            mujoco.mj_setState(m, d, self.state[i], STATE_SPEC)
            d.ctrl[:] = ctrl[k]
            d.xfrc_applied[:] = 0.0
            mujoco.mj_forward(m, d)
            self.sensordata[i] = d.sensordata
            self.traj[i] = self.state[i]

    def close(self) -> None:
        """Shut the thread pool down."""
        self._pool.close()


def make_physics(
    models: Sequence[mujoco.MjModel],
    nsub: int,
    nthread: int = 2,
    backend: str = "mujoco",
    bank: TerrainBank | None = None,
) -> BatchedPhysics:
    """The batched physics of ``backend`` (one of :data:`BACKENDS`); ValueError for another.
    ``bank``: the terrain the models' height field takes its tiles from (warp lays them all out
    on the device; the CPU engine rewrites each model's own height field)."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown physics backend '{backend}'; choose {' or '.join(BACKENDS)}")
    if backend == "warp":
        from tron1cli.env.physics_warp import WarpPhysics

        return WarpPhysics(models, nsub, bank=bank)
    return BatchedPhysics(models, nsub, nthread=nthread)
