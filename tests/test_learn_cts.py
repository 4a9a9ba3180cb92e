"""Vision-CTS: where each loss's gradient goes, the image path, the exported student."""

from __future__ import annotations

import dataclasses
import io
import warnings

import numpy as np
import pytest
import torch

from tron1cli.learn import LearnerConfig, ObsDims, VisionCTSLearner

torch.set_num_threads(1)

P, H, E, HM, HW = 5, 3, 7, 441, (12, 16)
N, T = 8, 4
GROUPS = ("stable", "loco")


def make(dims: ObsDims, seed: int = 0, **overrides) -> VisionCTSLearner:
    cfg = LearnerConfig(
        num_steps_per_env=T,
        num_epochs=2,
        num_minibatches=2,
        tbptt=2,
        rec_batch_envs=3,
        actor_hidden=(16,),
        critic_hidden=(16,),
        encoder_hidden=(16,),
        heightmap_encoder_hidden=(16,),
        decoder_hidden=(16,),
        depth_feature=8,
        gru_hidden=8,
        latent_e=4,
        latent_h=6,
        **overrides,
    )
    return VisionCTSLearner(dims, N, GROUPS, cfg, seed=seed)


def fake_obs(dims: ObsDims, rng: np.random.Generator, rows: int = N) -> dict[str, np.ndarray]:
    hist = rng.normal(size=(rows, dims.history)).astype(np.float32)
    obs = {
        "proprio": hist[:, -dims.proprio :].copy(),
        "history": hist,
        "privileged": rng.normal(size=(rows, dims.privileged)).astype(np.float32),
    }
    if dims.heightmap:
        obs["heightmap"] = (-0.6 + 0.05 * rng.normal(size=(rows, dims.heightmap))).astype(np.float32)
    if dims.depth_hw:
        obs["depth"] = rng.uniform(0.2, 3.5, size=(rows, *dims.depth_hw)).astype(np.float32)
    return obs


def fill(learner: VisionCTSLearner, rng: np.random.Generator) -> dict[str, np.ndarray]:
    dims = learner.dims
    obs = fake_obs(dims, rng)
    for t in range(T):
        learner.act(obs)
        obs = fake_obs(dims, rng)
        done = np.zeros(N, bool)
        done[[1, 6]] = t == 1  # a teacher and a student env end at step 1, the student by time-out
        time_out = done & (np.arange(N) == 6)
        rew = {g: rng.normal(size=N) for g in GROUPS}
        learner.process_step(rew, done, time_out, fake_obs(dims, rng))
    return obs


def grads(module) -> list[bool]:
    """Per parameter: has a non-zero gradient."""
    return [p.grad is not None and bool(p.grad.abs().sum() > 0) for p in module.parameters()]


@pytest.fixture(scope="module")
def vision() -> tuple[VisionCTSLearner, dict[str, np.ndarray]]:
    learner = make(ObsDims(P, H * P, E, heightmap=HM, depth_hw=HW))
    last = fill(learner, np.random.default_rng(0))
    return learner, last


def test_gradient_routes(vision):
    learner, last = vision
    m = learner.model
    learner.storage.compute_returns(torch.zeros(N, 2), 0.99, 0.95, learner.weights)
    teacher = [m.teacher_e, m.teacher_h]
    student = [m.est_e, m.dec_e, m.est_h, m.dec_h]
    heads = [m.actor, m.critics]

    m.zero_grad(set_to_none=True)
    loss, _ = learner.ppo_loss(torch.arange(T * N))
    loss.backward()
    assert not any(any(grads(s)) for s in student)  # stored student latents: fixed inputs
    assert all(all(grads(t)) for t in teacher)  # through the teacher rows' recomputed latents
    assert all(all(grads(h)) for h in heads) and m.log_std.grad is not None

    m.zero_grad(set_to_none=True)
    calls = []
    hook = m.teacher_h.register_forward_hook(lambda *_: calls.append(1))
    rec, parts = learner.reconstruction_loss(torch.arange(T * N))
    hook.remove()
    rec.backward()
    assert set(parts) == {"latent_e", "privileged"}  # the image path owns latent_h / heightmap
    assert not calls  # so no heightmap-encoder pass for targets nothing uses
    assert all(grads(m.est_e)) and all(grads(m.dec_e))
    assert not any(any(grads(x)) for x in teacher + heads + [m.est_h, m.dec_h])
    assert m.log_std.grad is None

    m.zero_grad(set_to_none=True)
    st = learner.storage
    loss, parts, hidden = learner.image_reconstruction_loss(0, 2, st.hidden0.clone())
    loss.backward()
    assert set(parts) == {"latent_h", "heightmap", "latent_h_reencoded", "heightmap_err_cm"}
    assert not parts["latent_h_reencoded"].requires_grad  # a figure at rec_reencode_coef = 0
    assert all(grads(m.est_h.cnn)) and all(grads(m.est_h.gru)) and all(grads(m.dec_h))
    assert not any(any(grads(x)) for x in teacher + heads + [m.est_e, m.dec_e])
    assert hidden.shape == (3, 8)
    m.zero_grad(set_to_none=True)


def test_vision_update_and_shapes(vision):
    learner, last = vision
    assert learner.storage.rec_env_ids.min() >= learner.n_teacher  # image path: student envs only
    before = [p.detach().clone() for p in learner.model.est_h.cnn.parameters()]
    stats = learner.update(last)
    assert all(np.isfinite(v) for v in stats.values())
    for k in (
        "rec_latent_e",
        "rec_latent_h",
        "rec_heightmap",
        "rec_privileged",
        "heightmap_err_cm",
        "value_loss/stable",
        "value_loss/loco",
    ):
        assert k in stats
    assert 0.0 < stats["heightmap_err_cm"] < 100.0
    after = list(learner.model.est_h.cnn.parameters())
    assert any(not torch.equal(a, b) for a, b in zip(after, before, strict=True))
    obs = fake_obs(learner.dims, np.random.default_rng(1))
    a, hid, h_hat, e_hat = learner.student_step(obs)
    assert a.shape == (N, 6) and hid.shape == (N, 8) and h_hat.shape == (N, HM) and e_hat.shape == (N, E)
    assert np.isfinite(h_hat).all() and np.isfinite(e_hat).all()


@pytest.mark.parametrize("reencode_h", [False, True])
@pytest.mark.parametrize("variant", ["depth", "heightmap", "blind"])
def test_export_matches_learner_student_action(variant, reencode_h):
    dims = {
        "depth": ObsDims(P, H * P, E, heightmap=HM, depth_hw=HW),
        "heightmap": ObsDims(P, H * P, E, heightmap=HM),
        "blind": ObsDims(P, H * P, E),
    }[variant]
    learner = make(dims, seed=1, reencode_h=reencode_h)
    rng = np.random.default_rng(2)
    obs = fake_obs(dims, rng)
    learner.act(obs)  # normalisers now hold these observations
    st, nt = learner.storage, learner.n_teacher
    pol = learner.policy_for_export()
    hist = torch.from_numpy(obs["history"][nt:])
    depth = torch.from_numpy(obs["depth"][nt:]) if dims.depth_hw else torch.zeros(N - nt, 1, 1)
    mean, hidden, h_hat, e_hat = pol(hist, depth, torch.zeros(N - nt, 8))
    torch.testing.assert_close(mean, st.mu[0, nt:], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(hidden, learner.hidden, rtol=1e-5, atol=1e-6)
    assert h_hat.shape == (N - nt, HM if dims.heightmap else 0) and e_hat.shape == (N - nt, E)
    a2, *_ = learner.student_step({k: v[nt:] for k, v in obs.items()})
    np.testing.assert_allclose(a2, mean.numpy(), rtol=1e-5, atol=1e-6)
    # the exported copy is frozen: training the learner further leaves it unchanged
    with torch.no_grad():
        learner.model.actor[0].weight.add_(1.0)
    torch.testing.assert_close(pol(hist, depth, torch.zeros(N - nt, 8))[0], mean)


@pytest.mark.parametrize("reencode_h", [False, True])
def test_export_onnx_parity(reencode_h):
    ort = pytest.importorskip("onnxruntime")
    dims = ObsDims(P, H * P, E, heightmap=HM, depth_hw=HW)
    learner = make(dims, reencode_h=reencode_h)
    learner.act(fake_obs(dims, np.random.default_rng(3)))
    pol = learner.policy_for_export()
    args = (torch.randn(2, H * P), torch.rand(2, *HW) * 3.0, torch.randn(2, 8))
    names = ["history", "depth", "hidden"]
    buf = io.BytesIO()
    with warnings.catch_warnings():  # the TorchScript exporter (needs no onnxscript) is deprecated
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(
            pol,
            args,
            buf,
            input_names=names,
            output_names=["action", "hidden_next", "h_hat", "e_hat"],
            dynamo=False,
        )
    sess = ort.InferenceSession(buf.getvalue())
    outs = sess.run(None, {n: a.numpy() for n, a in zip(names, args, strict=True)})
    for o, r in zip(outs, pol(*args), strict=True):
        np.testing.assert_allclose(o, r.numpy(), rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("ratio", [0.0, 1.0])
def test_single_group_runs(ratio):
    dims = ObsDims(P, H * P, E, heightmap=HM, depth_hw=HW)
    learner = make(dims)
    cfg = dataclasses.replace(learner.cfg, teacher_ratio=ratio, rec_all_envs=False)
    learner = VisionCTSLearner(dims, N, GROUPS, cfg, seed=0)
    stats = learner.update(fill(learner, np.random.default_rng(4)))
    assert all(np.isfinite(v) for v in stats.values())
    assert ("heightmap_err_cm" in stats) == (ratio < 1.0)


def test_student_warmup_forces_teacher_latents_then_releases():
    """During ``student_warmup`` updates the student rows act on their own e_t, h_t through the teacher
    encoders while the GRU advances as without forcing; afterwards they act on their own latents."""
    dims = ObsDims(P, H * P, E, heightmap=HM, depth_hw=HW)
    forced, free = make(dims), make(dims)
    forced.cfg = dataclasses.replace(forced.cfg, student_warmup=1)
    rng = np.random.default_rng(3)
    obs = fake_obs(dims, rng)
    forced.act(obs)
    free.act(obs)
    nt = forced.n_teacher
    st = forced.storage
    with torch.no_grad():
        ob = forced.model.normalize(forced._tensors(obs, rows=N))
        le_t, lh_t = forced.model.teacher_latents(ob["privileged"][nt:], ob["heightmap"][nt:])
    assert torch.allclose(st.latent_e[0, nt:], le_t) and torch.allclose(st.latent_h[0, nt:], lh_t)
    assert not torch.allclose(free.storage.latent_h[0, nt:], lh_t)  # unforced: the student's own
    assert torch.equal(forced.hidden, free.hidden)  # the GRU advanced the same way
    for learner in (forced, free):
        for _ in range(1, T):
            learner.process_step({g: np.zeros(N) for g in GROUPS}, np.zeros(N, bool), np.zeros(N, bool))
            learner.act(obs)
        learner.process_step({g: np.zeros(N) for g in GROUPS}, np.zeros(N, bool), np.zeros(N, bool))
    assert forced.update(obs)["student_forced"] == 1.0 and free.update(obs)["student_forced"] == 0.0
    assert not forced.student_forced
    forced.act(obs)
    with torch.no_grad():
        ob = forced.model.normalize(forced._tensors(obs, rows=N))
        _, lh_t = forced.model.teacher_latents(ob["privileged"][nt:], ob["heightmap"][nt:])
    assert not torch.allclose(forced.storage.latent_h[0, nt:], lh_t)


def test_student_warmup_must_be_a_count():
    with pytest.raises(ValueError, match="student_warmup"):
        LearnerConfig(student_warmup=-1)


@pytest.mark.parametrize("epochs", [1, 3])
def test_rec_epochs_steps_the_image_path_per_pass(epochs):
    """Each pass of the image path takes T / tbptt optimiser steps of the CNN; the reported
    reconstruction figures are the first pass's, so they do not depend on the number of passes."""
    dims = ObsDims(P, H * P, E, heightmap=HM, depth_hw=HW)
    learner, one = make(dims), make(dims)
    learner.cfg = dataclasses.replace(learner.cfg, rec_epochs=epochs)
    last = fill(learner, np.random.default_rng(5))
    last_one = fill(one, np.random.default_rng(5))
    stats, stats_one = learner.update(last), one.update(last_one)
    cnn_weight = next(learner.model.est_h.cnn.parameters())
    assert int(learner.opt_rec.state[cnn_weight]["step"]) == epochs * (T // learner.cfg.tbptt)
    assert stats["heightmap_err_cm"] == pytest.approx(stats_one["heightmap_err_cm"], rel=1e-5)


def test_rec_reencode_coef_adds_the_reencoded_latent_regression():
    """rec_reencode_coef adds coef x MSE(l2(enc^{t,h}(h_hat)), l^{t,h}) to the image path's loss; its
    gradient reaches the estimator through h_hat and leaves the teacher encoder to PPO."""
    dims = ObsDims(P, H * P, E, heightmap=HM, depth_hw=HW)
    plain, weighted = make(dims, seed=5), make(dims, seed=5, rec_reencode_coef=2.0)
    for learner in (plain, weighted):
        fill(learner, np.random.default_rng(5))
    hidden0 = plain.storage.hidden0.clone()
    loss_p, parts_p, _ = plain.image_reconstruction_loss(0, 2, hidden0.clone())
    loss_w, parts_w, _ = weighted.image_reconstruction_loss(0, 2, hidden0.clone())
    torch.testing.assert_close(parts_w["latent_h_reencoded"], parts_p["latent_h_reencoded"])
    torch.testing.assert_close(loss_w - loss_p, 2.0 * parts_w["latent_h_reencoded"].detach())
    m = weighted.model
    loss_w.backward()
    loss_p.backward()
    first = next(m.dec_h.parameters()).grad
    assert not torch.allclose(first, next(plain.model.dec_h.parameters()).grad)
    assert {id(p) for p in m.teacher_h.parameters()}.isdisjoint(id(p) for p in m.estimator_parameters())
    with pytest.raises(ValueError, match="rec_reencode_coef"):
        LearnerConfig(rec_reencode_coef=-1.0)


def test_reencode_h_reads_the_teacher_encoding_of_the_reconstruction():
    """With reencode_h the student's heightmap latent is l2(enc^{t,h}(dec_h(l))) of its estimator's
    latent l, the teacher's latent of the reconstruction; without it, l itself."""
    dims = ObsDims(P, H * P, E, heightmap=HM, depth_hw=HW)
    plain, reenc = make(dims, seed=4), make(dims, seed=4, reencode_h=True)
    rng = np.random.default_rng(4)
    obs = fake_obs(dims, rng)
    hist = torch.from_numpy(obs["history"])
    depth = torch.from_numpy(obs["depth"])
    hidden = torch.zeros(N, 8)
    with torch.no_grad():
        _, lh_plain, h_plain = plain.model.student_latents(hist, depth, hidden)
        _, lh_reenc, h_reenc = reenc.model.student_latents(hist, depth, hidden)
        _, want = reenc.model.teacher_latents(torch.zeros(N, E), reenc.model.dec_h(lh_plain))
    torch.testing.assert_close(h_reenc, h_plain)  # same estimator, same GRU state
    torch.testing.assert_close(lh_reenc, want)
    assert not torch.allclose(lh_reenc, lh_plain)
    torch.testing.assert_close(lh_reenc.norm(dim=-1), torch.ones(N))
