"""The learner's shortcuts compute what the plain computation does, to float tolerance.

Each test holds a plain reference (masked teacher rows, one CNN pass per frame, torch's ELU, the
unfused Adam) and checks the learner's faster path against it: the PPO loss and its gradients on a
fixed rollout, the cached CNN features of held 30 Hz frames at collection, the shared features of
the image path, the ELU, and whole updates.
"""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np
import torch
from test_learn_cts import GROUPS, HW, N, P, fake_obs, make
from torch import nn

from tron1cli.learn import ObsDims
from tron1cli.learn.models import ELU
from tron1cli.learn.ppo import _LOG_SQRT_2PI, _gaussian_log_prob

torch.set_num_threads(1)
DIMS = ObsDims(P, 3 * P, 7, heightmap=441, depth_hw=HW)


def rollout(learner, rng: np.random.Generator, hold_every: int = 2) -> dict[str, np.ndarray]:
    """Fill the rollout; every other step the even envs keep their depth frame (a held capture)."""
    obs = fake_obs(DIMS, rng)
    for t in range(learner.cfg.num_steps_per_env):
        learner.act(obs)
        nxt = fake_obs(DIMS, rng)
        if t % hold_every == 0:
            nxt["depth"][::2] = obs["depth"][::2]
        done = np.zeros(N, bool)
        done[[1, 6]] = t == 1
        learner.process_step({g: rng.normal(size=N) for g in GROUPS}, done, done & (np.arange(N) == 6), nxt)
        obs = nxt
    return obs


def reference_ppo_loss(learner, idx: torch.Tensor, ent_c: float) -> torch.Tensor:
    """The PPO loss written plainly: teacher latents put into their rows by a boolean mask."""
    m, st, cfg = learner.model, learner.storage, learner.cfg
    o, e, h = (st.flat(k)[idx] for k in ("proprio", "privileged", "heightmap"))
    le, lh = st.flat("latent_e")[idx], st.flat("latent_h")[idx]
    tm = learner._is_teacher[idx]
    le_t, lh_t = m.teacher_latents(e[tm], h[tm])
    le, lh = le.index_put((tm,), le_t), lh.index_put((tm,), lh_t)
    mu = m.action_mean(o, le, lh)
    ratio = torch.exp(
        _gaussian_log_prob(st.flat("actions")[idx], mu, m.log_std.expand_as(mu)) - st.flat("log_probs")[idx]
    )
    adv = st.flat("advantages")[idx]
    surrogate = -torch.min(adv * ratio, adv * torch.clamp(ratio, 1 - cfg.clip, 1 + cfg.clip)).mean()
    v, v_old, ret = m.values(e, h, le, lh), st.flat("values")[idx], st.flat("returns")[idx]
    v_clip = v_old + torch.clamp(v - v_old, -cfg.clip, cfg.clip)
    vloss = torch.max((v - ret).square(), (v_clip - ret).square()).mean(dim=0)
    entropy = (m.log_std + 0.5 + _LOG_SQRT_2PI).sum()
    return surrogate + cfg.value_coef * vloss.sum() - ent_c * entropy


def test_ppo_loss_and_gradients_match_the_plain_computation():
    learner = make(DIMS)
    last = rollout(learner, np.random.default_rng(1))
    with torch.no_grad():
        values = learner._values_of(last, torch.arange(N))
        learner.storage.compute_returns(values, learner.cfg.gamma, learner.cfg.lam, learner.weights)
    params = learner.model.ppo_parameters()
    idx = torch.randperm(learner.cfg.num_steps_per_env * N, generator=torch.Generator().manual_seed(0))[:20]
    assert 0 < int(learner._is_teacher[idx].sum()) < 20  # both groups in the minibatch
    loss, _ = learner.ppo_loss(idx, 0.01)
    fast = torch.autograd.grad(loss, params)
    ref_loss = reference_ppo_loss(learner, idx, 0.01)
    ref = torch.autograd.grad(ref_loss, params)
    torch.testing.assert_close(loss, ref_loss, rtol=1e-5, atol=1e-6)
    for a, b in zip(fast, ref, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)


def test_held_frames_reuse_cnn_features_with_the_same_result():
    cached, plain = make(DIMS, seed=2), make(DIMS, seed=2)
    plain._image_features = lambda depth: plain.model.est_h.cnn(depth)  # one pass per frame
    rows = []
    cached.model.est_h.cnn.register_forward_hook(lambda mod, inp, out: rows.append(inp[0].shape[0]))
    for learner in (cached, plain):
        rollout(learner, np.random.default_rng(3))
    st_c, st_p = cached.storage, plain.storage
    for name in ("actions", "latent_h", "latent_e", "values"):
        torch.testing.assert_close(getattr(st_c, name), getattr(st_p, name), rtol=1e-5, atol=1e-6)
    n_student, steps = N - cached.n_teacher, cached.cfg.num_steps_per_env
    held = (steps // 2) * (n_student // 2)  # even envs hold their frame every other step
    assert sum(rows) == n_student * steps - held + 1  # + the time-out bootstrap of student env 6


def test_image_path_shares_features_of_held_frames_exactly():
    learner = make(DIMS)
    rng = np.random.default_rng(4)
    frames = torch.as_tensor(rng.uniform(0.2, 3.5, size=(5, 3, *HW)).astype(np.float32))
    frames[1, 0] = frames[0, 0]  # env 0 holds over steps 0-2, env 2 over 3-4
    frames[2, 0] = frames[0, 0]
    frames[4, 2] = frames[3, 2]
    frames[3, 1] = frames[1, 1]  # equal to an older frame, not the previous one: a new pass
    cnn = learner.model.est_h.cnn
    params = list(cnn.parameters())
    weights = torch.as_tensor(rng.normal(size=(15, learner.cfg.depth_feature)).astype(np.float32))
    shared = learner._chunk_image_features(frames)
    plain = cnn(frames.reshape(15, *HW))
    torch.testing.assert_close(shared, plain, rtol=1e-6, atol=1e-6)
    g_shared = torch.autograd.grad((shared * weights).sum(), params)
    g_plain = torch.autograd.grad((plain * weights).sum(), params)
    for a, b in zip(g_shared, g_plain, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)


def test_bf16_update_moves_the_weights_as_fp32_does():
    """bfloat16 products (8-bit mantissa) change the update by about a per cent, not its direction."""
    before = make(DIMS, seed=5).model.state_dict()
    deltas = {}
    for precision in ("fp32", "bf16"):
        learner = make(DIMS, seed=5)
        learner.cfg = replace(learner.cfg, precision=precision)
        last = rollout(learner, np.random.default_rng(6))
        learner.update(last)
        after = learner.model.state_dict()
        deltas[precision] = torch.cat(
            [(after[k] - before[k]).flatten() for k in before if before[k].dtype == torch.float32]
        )
    a, b = deltas["fp32"], deltas["bf16"]
    assert a.norm() > 0
    assert torch.nn.functional.cosine_similarity(a, b, dim=0) > 0.999
    assert (a - b).norm() / a.norm() < 0.05


def test_elu_matches_torch_elu_in_value_and_gradient():
    special = torch.tensor([0.0, -0.0, 1e-8, -1e-8, 1e-3, -1e-3, -20.0, -100.0, 50.0, 88.0])
    x = torch.cat([special, torch.randn(4000) * 3.0]).requires_grad_()
    x_ref = x.detach().clone().requires_grad_()
    y, y_ref = ELU()(x), nn.functional.elu(x_ref)
    torch.testing.assert_close(y, y_ref, rtol=1e-6, atol=1e-7)
    w = torch.randn_like(y)
    (y * w).sum().backward()
    (y_ref * w).sum().backward()
    torch.testing.assert_close(x.grad, x_ref.grad, rtol=1e-6, atol=1e-7)
    with torch.no_grad():  # collection's path, without autograd
        torch.testing.assert_close(ELU()(x), y_ref, rtol=1e-6, atol=1e-7)
    edges = ELU()(torch.tensor([float("inf"), float("-inf"), float("nan")]))
    assert edges[0] == float("inf") and edges[1] == -1.0 and torch.isnan(edges[2])


def _as_before(learner):
    """The learner with the plain pieces its fast ones replace: torch's ELU modules, unfused Adam."""
    for module in list(learner.model.modules()):
        for name, child in list(module.named_children()):
            if isinstance(child, ELU):
                setattr(module, name, nn.ELU())
    cfg, m = learner.cfg, learner.model
    learner.opt_ppo = torch.optim.Adam(m.ppo_parameters(), lr=cfg.lr, foreach=False)
    learner.opt_rec = torch.optim.Adam(m.estimator_parameters(), lr=cfg.rec_lr, foreach=False)
    return learner


def test_updates_match_those_with_torch_elu_and_the_unfused_adam():
    fast, plain = make(DIMS, seed=7), _as_before(make(DIMS, seed=7))
    assert not any(isinstance(mod, nn.ELU) for mod in fast.model.modules())
    for learner in (fast, plain):
        rng = np.random.default_rng(8)
        for _ in range(2):  # the second rollout is collected by the updated networks
            learner.update(rollout(learner, rng))
    a, b = fast.model.state_dict(), plain.model.state_dict()
    moved = [k for k in a if not torch.equal(a[k], make(DIMS, seed=7).model.state_dict()[k])]
    assert "actor.0.weight" in moved and "est_h.cnn.conv.0.weight" in moved
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=1e-4, atol=1e-5, msg=k)


def test_a_checkpoint_of_the_unfused_adam_loads_into_a_fused_one_and_trains_on():
    saved = make(DIMS, seed=9)
    saved.update(rollout(saved, np.random.default_rng(10)))
    sd = copy.deepcopy(saved.state_dict())  # as read from disk: no tensor shared with ``saved``
    for key in ("optim_ppo", "optim_rec"):  # as checkpoints written before the fused update say
        for group in sd[key]["param_groups"]:
            group["fused"] = False
    learner = make(DIMS, seed=9)
    learner.load_state_dict(sd)
    assert all(g["fused"] for opt in (learner.opt_ppo, learner.opt_rec) for g in opt.param_groups)
    learner.update(rollout(learner, np.random.default_rng(11)))
    saved.update(rollout(saved, np.random.default_rng(11)))
    torch.testing.assert_close(learner.model.state_dict(), saved.model.state_dict(), rtol=1e-5, atol=1e-6)
