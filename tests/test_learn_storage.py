"""GAE per reward group, the normalised multi-critic advantage, time-out bootstraps, the normaliser."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tron1cli.learn import (
    LearnerConfig,
    ObsDims,
    RolloutStorage,
    RunningNormalizer,
    VisionCTSLearner,
    compute_gae,
    normalize_advantages,
)

torch.set_num_threads(1)

GAMMA, LAM = 0.9, 0.8


def test_gae_per_group_hand_computed():
    """T=3, N=2, G=2.

    env 0: a time-out at step 1 (terminal values 4.0 / -1.0 bootstrap its reward), running at the end.
    env 1: a failure at step 0 (no bootstrap), running at the end.
    """
    dims = ObsDims(proprio=1, history=1, privileged=1, action=1)
    st = RolloutStorage(3, 2, dims, latent_e=1, latent_h=0, num_groups=2, rec_envs=0, gru_hidden=1)
    r = torch.tensor([[[1.0, 10.0], [1.0, 1.0]], [[2.0, 20.0], [0.0, 0.0]], [[3.0, 30.0], [2.0, 2.0]]])
    done = torch.tensor([[False, True], [True, False], [False, False]])
    time_out = torch.tensor([[False, False], [True, False], [False, False]])
    terminal = torch.tensor([[4.0, -1.0], [100.0, 100.0]])  # env 1 row unused: no time-out there
    for t in range(3):
        st.store_rewards(t, r[t], done[t], time_out[t], terminal if time_out[t].any() else None, GAMMA)
    st.values.copy_(
        torch.tensor([[[0.5, 5.0], [1.0, 1.0]], [[1.0, 10.0], [0.5, 0.5]], [[1.5, 15.0], [1.0, 1.0]]])
    )
    last = torch.tensor([[2.0, 20.0], [3.0, 3.0]])
    st.compute_returns(last, GAMMA, LAM, torch.tensor([1.0, 1.0]))

    # env 0, group 0: r' = [1, 2 + 0.9 * 4, 3] = [1, 5.6, 3]
    #   A2 = 3 + 0.9 * 2 - 1.5 = 3.3;  A1 = 5.6 - 1.0 = 4.6 (done: no next value, no carry)
    #   A0 = (1 + 0.9 * 1.0 - 0.5) + 0.9 * 0.8 * 4.6 = 1.4 + 3.312 = 4.712
    # env 0, group 1: r' = [10, 20 + 0.9 * (-1), 30] = [10, 19.1, 30]
    #   A2 = 30 + 18 - 15 = 33;  A1 = 19.1 - 10 = 9.1;  A0 = (10 + 9 - 5) + 0.72 * 9.1 = 20.552
    # env 1 (both groups equal): done at step 0
    #   A2 = 2 + 0.9 * 3 - 1 = 3.7;  A1 = (0 + 0.9 * 1 - 0.5) + 0.72 * 3.7 = 0.4 + 2.664 = 3.064
    #   A0 = 1 - 1 = 0 (done: no carry from A1)
    adv = torch.tensor(
        [[[4.712, 20.552], [0.0, 0.0]], [[4.6, 9.1], [3.064, 3.064]], [[3.3, 33.0], [3.7, 3.7]]]
    )
    torch.testing.assert_close(st.returns, adv + st.values, rtol=1e-5, atol=1e-5)
    a, _ = compute_gae(st.rewards, st.values, st.dones, last, GAMMA, LAM)
    torch.testing.assert_close(a, adv, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(st.rewards[1, 0], torch.tensor([5.6, 19.1]))


def test_normalised_double_critic_advantage():
    g = torch.Generator().manual_seed(0)
    adv = torch.stack(
        [torch.randn(24, 32, generator=g) * 50.0 + 7.0, torch.randn(24, 32, generator=g) * 0.01 - 3.0], dim=-1
    )
    w = torch.tensor([1.0, 0.5])
    combined, normed = normalize_advantages(adv, w)
    flat = normed.reshape(-1, 2)
    torch.testing.assert_close(flat.mean(0), torch.zeros(2), atol=1e-5, rtol=0)
    torch.testing.assert_close(flat.std(0), torch.ones(2), atol=1e-4, rtol=0)
    torch.testing.assert_close(combined, normed[..., 0] + 0.5 * normed[..., 1])
    # each group's scale is gone: the tiny-reward group weighs as much as the big one
    assert abs(float(combined.std()) - float(torch.sqrt(torch.tensor(1.0 + 0.25)))) < 0.1


def test_learner_bootstraps_time_outs_from_its_critics():
    dims = ObsDims(proprio=2, history=4, privileged=3, action=1)
    cfg = LearnerConfig(
        actor_hidden=(8,),
        critic_hidden=(8,),
        encoder_hidden=(8,),
        decoder_hidden=(8,),
        critic_weights={"b": 0.5},
    )
    lr = VisionCTSLearner(dims, 4, ("a", "b"), cfg, seed=0)
    rng = np.random.default_rng(0)

    def obs():
        h = rng.normal(size=(4, 4)).astype(np.float32)
        return {
            "proprio": h[:, 2:].copy(),
            "history": h,
            "privileged": rng.normal(size=(4, 3)).astype(np.float32),
        }

    lr.act(obs())
    term = obs()
    time_out = np.array([True, False, False, True])  # one teacher env (0), one student env (3)
    lr.process_step({"a": np.ones(4), "b": np.zeros(4)}, np.array([True, True, False, True]), time_out, term)
    v = lr._values_of({k: x[time_out] for k, x in term.items()}, torch.tensor([0, 3]))
    expect = torch.tensor([[1.0, 0.0]] * 4)
    expect[[0, 3]] += cfg.gamma * v
    torch.testing.assert_close(lr.storage.rewards[0], expect)
    torch.testing.assert_close(lr.storage.dones[0], torch.tensor([1.0, 1.0, 0.0, 1.0]))
    torch.testing.assert_close(lr.weights, torch.tensor([1.0, 0.5]))
    with pytest.raises(ValueError):
        VisionCTSLearner(dims, 4, ("a",), cfg)  # a weight for an unknown group


def test_running_normalizer_matches_numpy():
    rng = np.random.default_rng(0)
    data = [rng.normal(3.0, 2.0, size=(n, 4)).astype(np.float32) for n in (5, 50, 1)]
    norm = RunningNormalizer(4, clip=5.0, eps=0.0)
    for d in data:
        norm.update(torch.from_numpy(d))
    allx = np.concatenate(data)
    np.testing.assert_allclose(norm.mean.numpy(), allx.mean(0), rtol=1e-5)
    np.testing.assert_allclose(norm.var.numpy(), allx.var(0), rtol=1e-4)
    x = torch.from_numpy(allx)
    y = norm(x)
    np.testing.assert_allclose(y.numpy(), np.clip((allx - allx.mean(0)) / allx.std(0), -5, 5), atol=1e-4)
    torch.testing.assert_close(norm.inverse(y), x, atol=1e-4, rtol=1e-4)
    assert float(norm(torch.full((1, 4), 1e6)).max()) == 5.0
    shared = RunningNormalizer(4, shared=True)
    shared.update(torch.from_numpy(allx))
    assert shared.mean.shape == (1,)
    np.testing.assert_allclose(float(shared.mean), allx.mean(), rtol=1e-5)
    off = RunningNormalizer(4, enabled=False)
    off.update(x)
    assert torch.equal(off(x), x)
