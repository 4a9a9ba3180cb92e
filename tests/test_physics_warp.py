"""The MuJoCo Warp backend (issue 22): the same arrays as the CPU engine, per-world randomised
fields, refusals. The tests that step warp are marked slow (its first call compiles kernels for
about 90 s on 2 cores) and need the ``warp`` extra; the refusals run in the default suite."""

from __future__ import annotations

import copy
import importlib.util
import os
import subprocess
import sys

import mujoco
import numpy as np
import pytest
from conftest import tron1

from tron1cli.env import robot
from tron1cli.env.physics import BatchedPhysics, make_physics
from tron1cli.env.scene import build_model
from tron1cli.env.terrain import TerrainBank, TerrainConfig

#: Largest |warp - CPU| of a state entry (m, rad, m/s, rad/s) after 200 substeps (1 s of falling,
#: landing and a push). Warp computes in float32 (relative eps 1.2e-7) and the CPU in float64; the
#: measured gap is 2e-5. 1e-3 is 50x that and still 10x below the 1 cm and 0.01 rad scale of
#: anything the env core reads or rewards.
STATE_TOL = 1e-3


def _worlds(n: int) -> list[mujoco.MjModel]:
    """``n`` copies of the flat-ground model, each with its own payload and foot friction."""
    m = build_model()
    models = [copy.copy(m) for _ in range(n)]
    base = m.body("base").id
    for i, mi in enumerate(models):
        mi.body_mass[base] += 1.0 * i
        mi.geom_friction[:, 0] = 0.4 + 0.2 * i
    return models


def _start(phys: BatchedPhysics, n: int) -> None:
    """Every world standing 0.83 m up in the default pose, at rest."""
    qpos = np.tile(phys.models[0].qpos0, (n, 1))
    qpos[:, 2] = 0.83
    qpos[:, 7:] = robot.DEFAULT_POSE
    phys.set_state(np.arange(n), qpos, np.zeros((n, phys.nv)))


def _run(phys: BatchedPhysics, n: int, steps: int = 50) -> np.ndarray:
    """Policy steps from the standing pose with the default targets and a 30 N push in steps
    20-24; the state after each, (steps, n, nstate)."""
    ctrl = np.tile(robot.DEFAULT_POSE, (n, phys.nsub, 1))
    out = []
    for k in range(steps):
        xfrc = np.zeros((n, 6))
        if 20 <= k < 25:
            xfrc[:, 0] = 30.0
        phys.step(ctrl, xfrc)
        out.append(phys.state.copy())
    return np.array(out)


def test_an_unknown_backend_is_refused():
    with pytest.raises(ValueError, match="unknown physics backend 'jax'"):
        make_physics(_worlds(1), 4, backend="jax")


def test_the_cli_refuses_an_unknown_backend_and_warp_off_flat_ground(tmp_path):
    r = tron1("train", "--backend", "jax", "--run-dir", str(tmp_path / "a"), "--iterations", "1")
    assert r.returncode == 2 and r.stderr.startswith("error: --backend: unknown physics backend 'jax'")
    assert r.stderr.count("\n") == 1
    r = tron1("bench", "--terrain", "stairs", "--backend", "warp")
    assert r.returncode == 2 and "flat ground only" in r.stderr and r.stderr.count("\n") == 1


@pytest.mark.skipif(importlib.util.find_spec("mujoco_warp") is not None, reason="mujoco-warp is installed")
def test_warp_without_mujoco_warp_installed_says_how_to_install_it(tmp_path):
    r = tron1("bench", "--backend", "warp", "--envs", "2", "--steps", "1")
    assert r.returncode == 2 and r.stderr.count("\n") == 1
    assert "pip install -e '.[warp]'" in r.stderr


def test_the_cpu_engine_syncs_nothing_and_reads_its_models():
    """sync is the backends' common hook after the randomiser writes models; the CPU engine reads
    the host models directly, so a model edit shows without it."""
    models = _worlds(2)
    phys = make_physics(models, 4, nthread=1)
    _start(phys, 2)
    phys.sync(np.array([0, 1]))
    states = _run(phys, 2, steps=5)
    assert not np.allclose(states[-1, 0, 1:], states[-1, 1, 1:])  # the payloads differ
    phys.close()


@pytest.mark.slow
def test_warp_follows_the_cpu_engine_world_by_world():
    pytest.importorskip("mujoco_warp")
    n = 4
    models = _worlds(n)
    cpu = make_physics(models, 4, nthread=1)
    gpu = make_physics(models, 4, backend="warp")
    for p in (cpu, gpu):
        _start(p, n)
    a, b = _run(cpu, n), _run(gpu, n)
    assert np.abs(a - b).max() < STATE_TOL
    assert np.abs(cpu.sensordata - gpu.sensordata).max() < 1e-2 * max(1.0, np.abs(cpu.sensordata).max())
    # the worlds' payloads and frictions made them differ, and warp followed each
    assert np.abs(a[-1, 1:] - a[-1, 0]).max() > 10 * STATE_TOL
    assert np.array_equal(gpu.traj[:, -1], gpu.state)
    cpu.close()
    gpu.close()


@pytest.mark.slow
def test_warp_sync_reaches_the_worlds_named_and_no_other():
    pytest.importorskip("mujoco_warp")
    n = 3
    m = build_model()
    models = [copy.copy(m) for _ in range(n)]
    gpu = make_physics(models, 4, backend="warp")
    base = models[0].body("base").id
    models[1].body_mass[base] += 3.0  # written on the host, not yet on the device
    _start(gpu, n)
    before = _run(gpu, n, steps=10)
    assert np.abs(before[:, 1] - before[:, 0]).max() < 1e-6  # the device still had the old mass
    gpu.sync(np.array([1]))
    _start(gpu, n)
    after = _run(gpu, n, steps=10)
    assert np.abs(after[:, 0] - before[:, 0]).max() < 1e-6
    assert np.abs(after[:, 2] - before[:, 2]).max() < 1e-6
    assert np.abs(after[:, 1] - after[:, 0]).max() > 1e-4
    gpu.close()


@pytest.mark.slow
def test_warp_refuses_height_field_terrain():
    pytest.importorskip("mujoco_warp")
    bank = TerrainBank.from_name("stairs", TerrainConfig(num_levels=2, variants_per_level=1), seed=0)
    with pytest.raises(ValueError, match="flat ground only"):
        make_physics([build_model(bank=bank)], 4, backend="warp")


@pytest.mark.slow
def test_a_tiny_training_run_on_warp_through_the_cli(tmp_path):
    pytest.importorskip("mujoco_warp")
    run = tmp_path / "run"
    env = dict(os.environ, OMP_NUM_THREADS="1")
    args = [sys.executable, "-m", "tron1cli", "train", "--backend", "warp", "--envs", "16"]
    r = subprocess.run(
        [*args, "--steps-per-env", "8", "--iterations", "2", "--run-dir", str(run)],
        capture_output=True,
        text=True,
        timeout=900,
        env=env,
    )
    assert r.returncode == 0, r.stderr
    assert "physics on warp (" in r.stdout + r.stderr
    assert (run / "checkpoints" / "latest.pt").is_file()
    lines = (run / "metrics.jsonl").read_text().splitlines()
    assert len(lines) == 2
