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


def _env(
    num_envs: int, seed: int, nthread: int, terrain: str, level: int, depth: bool, backend: str
) -> Tron1Env:
    cfg = EnvConfig(
        num_envs=num_envs,
        seed=seed,
        nthread=nthread,
        terrain=terrain,
        perception=depth,
        depth_from=num_envs // 2,
        max_init_level=level,
    )
    return Tron1Env(cfg, backend=backend)


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
    backend: str = "mujoco",
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
    env = _env(num_envs, seed, nthread, terrain, level, False, backend)
    denv = _env(num_envs, seed, nthread, terrain, level, True, backend) if depth else None
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
            "backend": backend,
            "terrain": terrain,
            "raw_steps_per_s": float(np.median(rates[0])),
            "env_steps_per_s": float(np.median(rates[1])),
            "depth": depth,
            # worlds the env core reset as diverged (NaN, runaway velocity, restarted clock):
            # a healthy engine has none; they would make the env rate a rate of resets
            "unstable_resets": env.unstable_count + (denv.unstable_count if denv is not None else 0),
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


def run_train_bench(
    cfg, rounds: int = 3, warmup: int = 1, device: str = "cpu", backend: str = "mujoco"
) -> dict:
    """Whole training iterations of ``cfg`` (a :class:`tron1cli.train.runner.RunConfig`) against the
    raw MuJoCo rate of the same physics, in one run.

    Each round trains one iteration, recording the physics state and controls of its T env steps,
    then replays them through ``mujoco.rollout`` alone (the raw rate). Returns the median rates of
    the whole iteration, its collection and its learning (env steps per second of each part) and
    each as a ratio of the raw rate, with the per-round spread ``[min, max]`` of every ratio. Rates
    are env steps over the median seconds of their rounds.
    """
    import tempfile
    from pathlib import Path

    from tron1cli.train.runner import Trainer

    if rounds < 1 or warmup < 0:
        raise ValueError("rounds must be >= 1 and warmup >= 0")
    T, n = cfg.learner.num_steps_per_env, cfg.env.num_envs
    with tempfile.TemporaryDirectory() as tmp:
        trainer = Trainer(Path(tmp), cfg, device=device, backend=backend)
        try:
            phys = trainer.env.physics
            states = np.empty((T,) + phys.state.shape)
            controls = np.empty((T,) + phys.control.shape)

            def before(env, t):
                states[t] = phys.state

            def after(env, t, res):
                controls[t] = phys.control

            obs = trainer.env.reset(stagger=True)
            for _ in range(warmup):
                obs, _ = trainer.iterate(obs)
            whole, collect, learn, raw = [], [], [], []
            for _ in range(rounds):
                obs, m = trainer.iterate(obs, before, after)
                collect.append(m["collect_s"])
                learn.append(m["learn_s"])
                whole.append(m["collect_s"] + m["learn_s"])
                saved = [a.copy() for a in (phys.state, phys.traj, phys.sensordata, phys.control)]
                # the replay runs on the arrays of the live physics: put them back afterwards
                t0 = time.perf_counter()
                for t in range(T):
                    phys.state[:] = states[t]
                    phys.control[:] = controls[t]
                    phys.rollout()
                raw.append(time.perf_counter() - t0)
                for dst, src in zip(
                    (phys.state, phys.traj, phys.sensordata, phys.control), saved, strict=True
                ):
                    dst[:] = src
            unstable = trainer.env.unstable_count
        finally:
            trainer.close()
    steps = T * n
    seconds = {"raw": raw, "train": whole, "collect": collect, "learn": learn}
    rates = {k: steps / np.array(v) for k, v in seconds.items()}
    res = {
        "num_envs": n,
        "steps_per_env": T,
        "epochs": cfg.learner.num_epochs,
        "rounds": rounds,
        "terrain": cfg.env.terrain,
        "perception": cfg.env.perception,
        "nthread": cfg.env.nthread,
        "backend": backend,
        "device": device,
        "precision": cfg.learner.precision,
        "raw_steps_per_s": steps / float(np.median(raw)),
        "collect_s": float(np.median(collect)),
        "learn_s": float(np.median(learn)),
        "unstable_resets": unstable,
    }
    for k in ("train", "collect", "learn"):
        res[f"{k}_steps_per_s"] = steps / float(np.median(seconds[k]))
        res[f"{k}_ratio"] = res[f"{k}_steps_per_s"] / res["raw_steps_per_s"]
        res[f"{k}_ratio_spread"] = _spread(rates[k] / rates["raw"])
    res["learn_over_collect"] = res["learn_s"] / res["collect_s"]
    res.update({"cpu_count": os.cpu_count(), "machine": platform.machine()})
    return res
