"""``tron1 bench``: the env core's step rate as a ratio of the raw MuJoCo rate, in one run.

The raw rate is measured on exactly the env's own workload: the bench records the state and the
controls that every env step handed to ``mujoco.rollout`` and then replays them through rollout
alone, so the ratio counts what the env core adds (observations, commands, terminations, resets)
and nothing else.
"""

from __future__ import annotations

import os
import platform
import time

import numpy as np

from tron1cli.config import EnvConfig
from tron1cli.env.core import Tron1Env


def run_bench(
    num_envs: int = 1024, steps: int = 100, warmup: int = 10, seed: int = 0, nthread: int = 2
) -> dict:
    """Measure raw and env policy-step rates; returns a flat dict of figures."""
    env = Tron1Env(EnvConfig(num_envs=num_envs, seed=seed, nthread=nthread))
    try:
        env.reset()
        rng = np.random.default_rng(seed)
        actions = rng.normal(0.0, 0.5, (warmup + steps, num_envs, 6))
        for i in range(warmup):
            env.step(actions[i])
        phys = env.physics
        states = np.empty((steps,) + phys.state.shape)
        controls = np.empty((steps,) + phys.control.shape)
        env_seconds = 0.0
        for i in range(steps):
            states[i] = phys.state
            t0 = time.perf_counter()
            env.step(actions[warmup + i])
            env_seconds += time.perf_counter() - t0
            controls[i] = phys.control
        t0 = time.perf_counter()
        for i in range(steps):
            phys.state[:] = states[i]
            phys.control[:] = controls[i]
            phys.rollout()
        raw_seconds = time.perf_counter() - t0
    finally:
        env.close()
    raw = steps * num_envs / raw_seconds
    full = steps * num_envs / env_seconds
    return {
        "num_envs": num_envs,
        "steps": steps,
        "decimation": env.cfg.decimation,
        "nthread": nthread,
        "terrain": env.cfg.terrain,
        "raw_steps_per_s": raw,
        "env_steps_per_s": full,
        "ratio": full / raw,
        "cpu_count": os.cpu_count(),
        "machine": platform.machine(),
    }
