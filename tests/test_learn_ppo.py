"""PPO of tron1cli.learn on a tiny vectorised point-mass task, fed through the env contract."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch

from tron1cli.learn import LearnerConfig, ObsDims, VisionCTSLearner

torch.set_num_threads(1)

GROUPS = ("near", "far")


class PointMass:
    """1-D point mass pushed towards a random target.

    obs o_t = (x - target, v); action: force = 2 * clip(a, -1, 1); dt 0.1 s; 40-step episodes ending in a
    time-out; an error above 4 m is a failure. Rewards in two aligned groups: ``near`` = exp(-4 err^2)
    (minus 2 on failure) and ``far`` = -0.2 |err| - 0.01 force^2. A hand-tuned PD controller scores
    about 28-30 per episode (both groups summed), random actions about 0.
    """

    def __init__(self, n: int, seed: int, ep_len: int = 40) -> None:
        self.n, self.ep_len = n, ep_len
        self.rng = np.random.default_rng(seed)
        self.x, self.v, self.tgt = np.zeros(n), np.zeros(n), np.zeros(n)
        self.t = np.zeros(n, dtype=int)
        self.prev = np.zeros((n, 2), np.float32)
        self._reset(np.arange(n))
        self.t[:] = self.rng.integers(0, ep_len, n)  # desynchronise the time-outs

    def _o(self) -> np.ndarray:
        return np.stack([self.x - self.tgt, self.v], -1).astype(np.float32)

    def _reset(self, ids: np.ndarray) -> None:
        self.x[ids] = self.rng.uniform(-2, 2, len(ids))
        self.v[ids] = 0.0
        self.tgt[ids] = self.rng.uniform(-1, 1, len(ids))
        self.t[ids] = 0
        self.prev[ids] = self._o()[ids]

    def obs(self) -> dict[str, np.ndarray]:
        o = self._o()
        return {"proprio": o, "history": np.concatenate([self.prev, o], 1), "privileged": o.copy()}

    def step(self, a: np.ndarray):
        f = np.clip(a[:, 0], -1, 1) * 2.0
        self.prev = self._o()
        self.v = self.v + 0.1 * f
        self.x = self.x + 0.1 * self.v
        self.t += 1
        err = self.x - self.tgt
        fail = np.abs(err) > 4
        rew = {"near": np.exp(-4 * err**2) - 2.0 * fail, "far": -0.2 * np.abs(err) - 0.01 * f**2}
        time_out = (self.t >= self.ep_len) & ~fail
        done = fail | time_out
        terminal = self.obs()
        ids = np.nonzero(done)[0]
        if len(ids):
            self._reset(ids)
        return self.obs(), rew, done, time_out, terminal


DIMS = ObsDims(proprio=2, history=4, privileged=2, action=1)


def small_cfg(**kw) -> LearnerConfig:
    base = dict(
        actor_hidden=(64, 64),
        critic_hidden=(64, 64),
        encoder_hidden=(32,),
        heightmap_encoder_hidden=(32,),
        decoder_hidden=(32,),
        latent_e=4,
        entropy_coef=0.001,
        entropy_coef_final=0.001,
        init_noise_std=0.5,
    )
    base.update(kw)
    return LearnerConfig(**base)


def run(learner: VisionCTSLearner, env: PointMass, iters: int) -> tuple[list[float], list[dict]]:
    obs = env.obs()
    ep = np.zeros(env.n)
    returns, stats = [], []
    for _ in range(iters):
        finished = []
        for _ in range(learner.cfg.num_steps_per_env):
            a = learner.act(obs)
            obs, rew, done, time_out, terminal = env.step(a)
            ep += rew["near"] + rew["far"]
            learner.process_step(rew, done, time_out, terminal)
            finished += list(ep[done])
            ep[done] = 0.0
        stats.append(learner.update(obs))
        returns.append(float(np.mean(finished)) if finished else float("nan"))
    return returns, stats


def test_ppo_learns_point_mass():
    # measured (seeds 0-2): iterations 0-2 at -4..2 per episode, iterations 20-24 at 28-31
    learner = VisionCTSLearner(DIMS, 64, GROUPS, small_cfg(), seed=0)
    returns, stats = run(learner, PointMass(64, seed=0), 25)
    assert np.nanmean(returns[:3]) < 8.0
    assert np.nanmean(returns[-5:]) > 22.0, returns
    last = stats[-1]
    assert all(np.isfinite(v) for v in last.values())
    assert {
        "value_loss/near",
        "value_loss/far",
        "surrogate_loss",
        "entropy",
        "kl",
        "lr",
        "action_std",
        "rec_latent_e",
        "rec_privileged",
        "learn_s",
    } <= set(last)
    assert last["rec_latent_e"] < stats[0]["rec_latent_e"]  # the student estimator learns too


def test_same_seed_same_first_update():
    out = []
    for _ in range(2):
        learner = VisionCTSLearner(DIMS, 16, GROUPS, small_cfg(), seed=3)
        _, stats = run(learner, PointMass(16, seed=5), 1)
        out.append({k: v for k, v in stats[0].items() if k != "learn_s"})
    assert out[0] == out[1]
    other = VisionCTSLearner(DIMS, 16, GROUPS, small_cfg(), seed=4)
    _, stats = run(other, PointMass(16, seed=5), 1)
    assert stats[0]["surrogate_loss"] != out[0]["surrogate_loss"]


def test_state_dict_roundtrip_weights_only():
    env = PointMass(16, seed=1)
    learner = VisionCTSLearner(DIMS, 16, GROUPS, small_cfg(), seed=0)
    run(learner, env, 1)
    buf = io.BytesIO()
    torch.save(learner.state_dict(), buf)
    buf.seek(0)
    sd = torch.load(buf, weights_only=True)
    clone = VisionCTSLearner(DIMS, 16, GROUPS, small_cfg(), seed=99)
    clone.load_state_dict(sd)
    assert clone.iteration == learner.iteration == 1 and clone.lr == learner.lr
    obs = env.obs()
    np.testing.assert_array_equal(clone.act(obs), learner.act(obs))
    rebuilt = VisionCTSLearner.from_state_dict(sd)
    assert rebuilt.cfg == learner.cfg
    with pytest.raises(ValueError):
        VisionCTSLearner(DIMS, 16, ("near",), small_cfg()).load_state_dict(sd)


def test_contract_errors():
    learner = VisionCTSLearner(DIMS, 4, GROUPS, small_cfg(), seed=0)
    obs = PointMass(4, seed=0).obs()
    bad = dict(obs, history=obs["history"][:, ::-1].copy())
    with pytest.raises(ValueError, match="last P entries"):
        learner.act(bad)
    with pytest.raises(RuntimeError):
        learner.update(obs)
    learner.act(obs)
    with pytest.raises(ValueError, match="terminal_obs"):
        learner.process_step({"near": np.zeros(4), "far": np.zeros(4)}, np.ones(4, bool), np.ones(4, bool))
