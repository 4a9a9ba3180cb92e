"""``tron1 bench``: the env core's step rate as a ratio of the raw MuJoCo rate, in one run.

The raw rate is measured on exactly the env's own workload: the bench records the state and the
controls that every env step handed to ``mujoco.rollout`` and then replays them through rollout
alone, so the ratio counts what the env core adds (observations, commands, terminations, resets)
and nothing else. Rounds of env, raw and perceptive-env timing alternate and each rate is the
median of its rounds. With perception the sensors are also timed on their own: the 441-point height
scan and the 80 x 60 depth render of every env, from the states the run ended in.
"""

from __future__ import annotations

import os
import platform
import time

import numpy as np

from tron1cli.config import EnvConfig
from tron1cli.env.core import Tron1Env
from tron1cli.env.math3d import yaw_of


def _env(num_envs: int, seed: int, nthread: int, terrain: str, level: int, depth: bool) -> Tron1Env:
    cfg = EnvConfig(
        num_envs=num_envs,
        seed=seed,
        nthread=nthread,
        terrain=terrain,
        perception=depth,
        depth_from=num_envs // 2,
        max_init_level=level,
    )
    return Tron1Env(cfg)


def _time_env(env: Tron1Env, actions: np.ndarray, warmup: int, record: bool):
    """Seconds spent in ``env.step`` over the timed steps; with ``record`` also the rollout inputs."""
    env.reset()
    for i in range(warmup):
        env.step(actions[i])
    phys = env.physics
    steps = len(actions) - warmup
    states = np.empty((steps,) + phys.state.shape) if record else None
    controls = np.empty((steps,) + phys.control.shape) if record else None
    seconds = 0.0
    for i in range(steps):
        if record:
            states[i] = phys.state
        t0 = time.perf_counter()
        env.step(actions[warmup + i])
        seconds += time.perf_counter() - t0
        if record:
            controls[i] = phys.control
    return seconds, states, controls


def run_bench(
    num_envs: int = 1024,
    steps: int = 100,
    warmup: int = 10,
    seed: int = 0,
    nthread: int = 2,
    terrain: str = "flat",
    depth: bool = False,
    level: int = 5,
    rounds: int = 3,
) -> dict:
    """Measure raw and env policy-step rates (and, with ``depth``, the perceptive env and its
    sensors); returns a flat dict of figures.

    The perceptive env renders depth at 30 Hz for the student half of the envs and scans heights
    for every env, as in training; non-flat terrain starts every env on difficulty ``level``.
    The measurements alternate over ``rounds`` rounds (env, raw replay, perceptive env) and each
    rate is the median of its rounds, so that a slow spell of a shared machine does not land on
    one side of a ratio only; ``*_spread`` gives (min, max) of each ratio over the rounds.
    """
    if rounds < 1:
        raise ValueError("rounds must be >= 1")
    rng = np.random.default_rng(seed)
    actions = rng.normal(0.0, 0.5, (warmup + steps, num_envs, 6))
    env = _env(num_envs, seed, nthread, terrain, level, depth=False)
    denv = _env(num_envs, seed, nthread, terrain, level, depth=True) if depth else None
    env_s, raw_s, depth_s = [], [], []
    try:
        states = controls = None
        for r in range(rounds):
            seconds, rec_states, rec_controls = _time_env(env, actions, warmup, record=r == 0)
            env_s.append(seconds)
            if r == 0:
                states, controls = rec_states, rec_controls
            phys = env.physics
            t0 = time.perf_counter()
            for i in range(steps):
                phys.state[:] = states[i]
                phys.control[:] = controls[i]
                phys.rollout()
            raw_s.append(time.perf_counter() - t0)
            if denv is not None:
                depth_s.append(_time_env(denv, actions, warmup, record=False)[0])
        rates = steps * num_envs / np.array([raw_s, env_s] + ([depth_s] if denv is not None else []))
        res = {
            "num_envs": num_envs,
            "steps": steps,
            "rounds": rounds,
            "decimation": env.cfg.decimation,
            "nthread": nthread,
            "terrain": terrain,
            "raw_steps_per_s": float(np.median(rates[0])),
            "env_steps_per_s": float(np.median(rates[1])),
            "depth": depth,
        }
        res["ratio"] = res["env_steps_per_s"] / res["raw_steps_per_s"]
        res["ratio_spread"] = _spread(rates[1] / rates[0])
        if denv is not None:
            res["env_depth_steps_per_s"] = float(np.median(rates[2]))
            res["depth_ratio"] = res["env_depth_steps_per_s"] / res["raw_steps_per_s"]
            res["depth_ratio_spread"] = _spread(rates[2] / rates[0])
            res.update(_time_sensors(denv))
    finally:
        env.close()
        if denv is not None:
            denv.close()
    res.update({"cpu_count": os.cpu_count(), "machine": platform.machine()})
    return res


def _spread(ratios: np.ndarray) -> list[float]:
    """[min, max] of per-round ratios."""
    return [float(ratios.min()), float(ratios.max())]


def _time_sensors(env: Tron1Env, repeats: int = 5) -> dict:
    """Height scans and depth images per second over every env (the env's own compiled code)."""
    ids = np.arange(env.n)
    s = env.state
    t0 = time.perf_counter()
    for _ in range(repeats):
        env.height_scan.scan(
            env.bank.heights, env.curriculum.tile, s.base_pos, yaw_of(s.base_quat), env.bank.res
        )
    scan_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(repeats):
        env._render_depth(ids)
    depth_s = time.perf_counter() - t0
    return {
        "heightmaps_per_s": repeats * env.n / scan_s,
        "depth_images_per_s": repeats * env.n / depth_s,
        "depth_ms_per_image": 1e3 * depth_s / (repeats * env.n),
    }
