"""Vision-CTS PPO learner with one critic per reward group (numpy in, numpy out).

How the latents enter the gradients
-----------------------------------
Envs ``[0, n_teacher)`` are teachers, the rest students; all share one policy and the critics.

- Student latents (l^{s,e}, l^{s,h}) are computed once, at collection, under ``torch.no_grad`` and stored.
  In the PPO minibatches the student rows feed these stored tensors to the policy and the critics as
  fixed inputs: the PPO loss has NO path into the student estimators (nor into the depth CNN or GRU),
  so no PPO minibatch runs the image path.
- Teacher latents (l^{t,e}, l^{t,h}) are recomputed inside every minibatch from the stored
  (normalised) e_t and h_t of the teacher rows, so the surrogate, the value losses and the entropy
  term back-propagate through the policy and the critics into the teacher encoders.
- The student estimators learn only from the reconstruction loss
  ``L_rec = MSE(l^{s,e}, sg(l^{t,e})) + MSE(l^{s,h}, sg(l^{t,h})) + MSE(h_hat, h) + MSE(e_hat, e)``
  (sg: stop-gradient; targets in normalised units) with their own Adam optimiser, so L_rec never
  reaches the teacher encoders, the policy or the critics. The MLP parts (privileged estimator; the
  history-only heightmap estimator of a run without depth) take one step per PPO minibatch on the same
  rows. The image path (CNN + GRU) runs ``rec_epochs`` passes per iteration over ``rec_batch_envs``
  student envs sampled at the start of the rollout, x the T steps, from the GRU states saved at that
  start, with truncated back-propagation through time: the state is detached and the optimiser steps every
  ``tbptt`` steps, and the state is zeroed after a done exactly as at collection.

Call order per iteration: T x (``act(obs)``, env step, ``process_step(...)``), then ``update(next_obs)``.
"""

from __future__ import annotations

import contextlib
import copy
import math
import time
from collections.abc import Mapping

import numpy as np
import torch
import torch.nn.functional as F

from tron1cli.learn.config import LearnerConfig, ObsDims, teacher_count
from tron1cli.learn.models import StudentPolicy, VisionCTS, l2_normalize
from tron1cli.learn.storage import RolloutStorage

CHECKPOINT_FORMAT = "tron1cli.learn/1"
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


def _gaussian_log_prob(a: torch.Tensor, mu: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    return (-0.5 * ((a - mu) * torch.exp(-log_std)).square() - log_std - _LOG_SQRT_2PI).sum(dim=-1)


def _use_fused_adam(opt: torch.optim.Adam) -> None:
    """Keep an Adam fused after ``load_state_dict`` (which restores the saved groups' flags; checkpoints
    written before the fused update say ``fused: False``). The fused update is the same Adam step in
    one kernel: 0.8 ms instead of 3.9 ms a step for the flat model's 189 k PPO parameters, measured on
    the 2-core AVX2 machine."""
    for group in opt.param_groups:
        group.update(fused=True, foreach=None)
        for p in group["params"]:
            state = opt.state.get(p, {})
            if "step" in state:
                state["step"] = state["step"].to(p.device, torch.float32)


class VisionCTSLearner:
    """PPO for Vision-CTS with a critic per reward group.

    dims: the observation widths of the run; num_envs: N (rows of every array exchanged);
    groups: reward-group names (one critic each, e.g. ("stable", "loco"), or ("all",));
    cfg: hyper-parameters; device: torch device; seed: model init, action sampling, minibatch order and
    the image path's env sample all derive from it (same seed and inputs -> same results).
    """

    def __init__(
        self,
        dims: ObsDims,
        num_envs: int,
        groups: tuple[str, ...],
        cfg: LearnerConfig | None = None,
        device: str | torch.device = "cpu",
        seed: int = 0,
    ) -> None:
        cfg = cfg if cfg is not None else LearnerConfig()
        groups = tuple(groups)
        if not groups or len(set(groups)) != len(groups):
            raise ValueError(f"reward groups must be non-empty and unique, got {groups}")
        for g in groups:
            if not isinstance(g, str) or not g or "." in g:
                raise ValueError(f"invalid reward-group name {g!r}")
        unknown = set(cfg.critic_weights) - set(groups)
        if unknown:
            raise ValueError(f"critic_weights name unknown reward groups {sorted(unknown)}; groups: {groups}")
        if int(num_envs) != num_envs or num_envs <= 0:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs}")
        self.dims, self.cfg, self.groups = dims, cfg, groups
        self.num_envs = N = int(num_envs)
        self.n_teacher = teacher_count(N, cfg.teacher_ratio)
        self.n_student = N - self.n_teacher
        self.device = torch.device(device)
        self.seed = int(seed)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(self.seed)
            self.model = VisionCTS(dims, groups, cfg)
        self.model.to(self.device)
        self.generator = torch.Generator(device=self.device)
        self.generator.manual_seed(self.seed)
        self.lr = cfg.lr
        self.opt_ppo = torch.optim.Adam(self.model.ppo_parameters(), lr=cfg.lr, fused=True)
        self.opt_rec = torch.optim.Adam(self.model.estimator_parameters(), lr=cfg.rec_lr, fused=True)
        self.rec_envs = min(cfg.rec_batch_envs, self.n_student) if self.model.depth_path else 0
        self.storage = RolloutStorage(
            cfg.num_steps_per_env,
            N,
            dims,
            self.model.latent_e_dim,
            self.model.latent_h_dim,
            len(groups),
            self.rec_envs,
            cfg.gru_hidden,
            self.device,
        )
        self.hidden = torch.zeros(self.n_student, cfg.gru_hidden, device=self.device)
        # the depth frame each student env saw at its last act() and its CNN features: a 30 Hz frame
        # held over a 50 Hz policy step is not run through the CNN again (None: nothing cached)
        self._frames: torch.Tensor | None = None
        self._frame_features: torch.Tensor | None = None
        self.weights = torch.tensor(
            [float(cfg.critic_weights.get(g, 1.0)) for g in groups], device=self.device
        )
        self.iteration = 0
        self.step = 0
        self._history_checked = False
        self._student = StudentPolicy(self.model)
        flat_env = torch.arange(cfg.num_steps_per_env * N, device=self.device) % N
        self._is_teacher = flat_env < self.n_teacher

    @property
    def student_forced(self) -> bool:
        """Whether the student envs act on teacher latents this iteration (``cfg.student_warmup``)."""
        return self.iteration < self.cfg.student_warmup

    # ------------------------------------------------------------------------------------------
    # observations
    def _tensors(self, obs: Mapping[str, np.ndarray], rows: int | None = None) -> dict[str, torch.Tensor]:
        d = self.dims
        want: dict[str, tuple[int, ...]] = {
            "proprio": (d.proprio,),
            "history": (d.history,),
            "privileged": (d.privileged,),
        }
        if d.has_heightmap:
            want["heightmap"] = (d.heightmap,)
        if d.depth_hw is not None:
            want["depth"] = tuple(d.depth_hw)
        out = {}
        for k, shape in want.items():
            if k not in obs:
                raise KeyError(f"observation group {k!r} missing (have {sorted(obs)})")
            x = torch.as_tensor(np.asarray(obs[k], dtype=np.float32), device=self.device)
            if tuple(x.shape[1:]) != shape or (rows is not None and x.shape[0] != rows):
                raise ValueError(f"observation {k!r} has shape {tuple(x.shape)}, expected ({rows}, *{shape})")
            out[k] = x
        return out

    def _check_history(self, raw: dict[str, torch.Tensor]) -> None:
        P = self.dims.proprio
        if not torch.allclose(raw["history"][:, -P:], raw["proprio"], atol=1e-5):
            raise ValueError(
                "contract: the last P entries of 'history' must equal 'proprio' (the current o_t)"
            )
        self._history_checked = True

    def _latents_rows(
        self, ob: dict[str, torch.Tensor], env_ids: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Latents of rows with the given env ids (teacher or student each), without advancing the GRU."""
        m = self.model
        R = env_ids.shape[0]
        le = torch.zeros(R, m.latent_e_dim, device=self.device)
        lh = torch.zeros(R, m.latent_h_dim, device=self.device)
        tm = (env_ids < self.n_teacher) | self.student_forced
        if tm.any():
            h = ob["heightmap"][tm] if "heightmap" in ob else None
            le[tm], lh[tm] = m.teacher_latents(ob["privileged"][tm], h)
        sm = ~tm
        if sm.any():
            depth = ob["depth"][sm] if "depth" in ob else None
            hidden = self.hidden[env_ids[sm] - self.n_teacher]
            le_s, lh_s, _ = m.student_latents(ob["history"][sm], depth, hidden)
            le[sm], lh[sm] = le_s, lh_s
        return le, lh

    @torch.no_grad()
    def _values_of(self, obs: Mapping[str, np.ndarray], env_ids: torch.Tensor) -> torch.Tensor:
        """V_g (R, G) of raw observation rows ``obs`` belonging to ``env_ids`` (normalisers not updated)."""
        raw = self._tensors(obs, rows=env_ids.shape[0])
        ob = self.model.normalize(raw)
        le, lh = self._latents_rows(ob, env_ids)
        return self.model.values(ob["privileged"], ob.get("heightmap"), le, lh)

    # ------------------------------------------------------------------------------------------
    # collection
    def _begin_rollout(self) -> None:
        st = self.storage
        if self.rec_envs > 0:
            pick = torch.randperm(self.n_student, generator=self.generator, device=self.device)[
                : self.rec_envs
            ]
            pick = torch.sort(pick).values
            st.rec_env_ids.copy_(pick + self.n_teacher)
            st.hidden0.copy_(self.hidden[pick])

    def _image_features(self, depth: torch.Tensor) -> torch.Tensor:
        """CNN features (n_student, depth_feature) of the students' frames, computed only for the envs
        whose frame differs from the one they saw at the previous act() (the cache lives until the
        next update, which changes the CNN)."""
        cnn = self.model.est_h.cnn
        if self._frames is None:
            self._frames = depth.clone()
            self._frame_features = cnn(depth)
            return self._frame_features
        new = torch.nonzero((depth != self._frames).flatten(1).any(dim=1)).squeeze(-1)
        if new.numel():
            self._frames[new] = depth[new]
            self._frame_features[new] = cnn(depth[new])
        return self._frame_features

    def _drop_image_cache(self) -> None:
        self._frames = self._frame_features = None

    @torch.no_grad()
    def act(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        """Sample actions (N, A) for observation groups with N rows; stores what PPO needs.

        Updates the observation normalisers with ``obs``, computes teacher latents for teacher rows and
        student latents for student rows (advancing each student env's GRU state).
        """
        T, nt = self.cfg.num_steps_per_env, self.n_teacher
        if self.step >= T:
            raise RuntimeError(f"the rollout already holds {T} steps: call update() first")
        m, st, t = self.model, self.storage, self.step
        raw = self._tensors(obs, rows=self.num_envs)
        if not self._history_checked:
            self._check_history(raw)
        if t == 0:
            self._begin_rollout()
        if self.cfg.obs_normalization:
            m.update_normalizers(raw)
        ob = m.normalize(raw)
        le, lh = st.latent_e[t], st.latent_h[t]
        if nt > 0:
            h = ob["heightmap"][:nt] if "heightmap" in ob else None
            le_t, lh_t = m.teacher_latents(ob["privileged"][:nt], h)
            le[:nt].copy_(le_t)
            lh[:nt].copy_(lh_t)
        if self.n_student > 0:
            depth = ob["depth"][nt:] if "depth" in ob else None
            feats = self._image_features(depth) if m.depth_path else None
            le_s, lh_s, hid = m.student_latents(ob["history"][nt:], depth, self.hidden, feats)
            self.hidden.copy_(hid)
            if self.student_forced:  # teacher forcing: the GRU advanced above, the policy sees e_t, h_t
                h = ob["heightmap"][nt:] if "heightmap" in ob else None
                le_s, lh_s = m.teacher_latents(ob["privileged"][nt:], h)
            le[nt:].copy_(le_s)
            lh[nt:].copy_(lh_s)
        if st.depth is not None:
            st.depth[t].copy_(raw["depth"][st.rec_env_ids])
        mu = m.action_mean(ob["proprio"], le, lh)
        log_std = m.log_std.expand_as(mu)
        std = torch.exp(log_std)
        a = mu + std * torch.randn(mu.shape, generator=self.generator, device=self.device)
        st.actions[t].copy_(a)
        st.log_probs[t].copy_(_gaussian_log_prob(a, mu, log_std))
        st.mu[t].copy_(mu)
        st.sigma[t].copy_(std)
        st.values[t].copy_(m.values(ob["privileged"], ob.get("heightmap"), le, lh))
        st.proprio[t].copy_(ob["proprio"])
        st.history[t].copy_(ob["history"])
        st.privileged[t].copy_(ob["privileged"])
        if "heightmap" in ob:
            st.heightmap[t].copy_(ob["heightmap"])
        return a.cpu().numpy()

    @torch.no_grad()
    def process_step(
        self,
        rewards: Mapping[str, np.ndarray],
        done: np.ndarray,
        time_out: np.ndarray,
        terminal_obs: Mapping[str, np.ndarray] | None = None,
    ) -> None:
        """Store the step's rewards (dict group -> (N,)) and dones; bootstrap time-outs.

        A timed-out env gets ``gamma * V_g(terminal_obs)`` added to its group-g reward (terminal_obs: the
        observation before the reset, all N rows; only timed-out rows are evaluated, with the GRU state
        the env had). A time-out counts as a done. Then the GRU states of done student envs are zeroed.
        """
        if self.step >= self.cfg.num_steps_per_env:
            raise RuntimeError("process_step() without a matching act()")
        N = self.num_envs
        missing = set(self.groups) - set(rewards)
        if missing:
            raise KeyError(f"rewards miss groups {sorted(missing)}")
        r = torch.stack(
            [
                torch.as_tensor(np.asarray(rewards[g], dtype=np.float32), device=self.device)
                for g in self.groups
            ],
            dim=-1,
        )
        if r.shape != (N, len(self.groups)):
            raise ValueError(f"each reward group must have shape ({N},)")
        to = torch.as_tensor(np.asarray(time_out, dtype=bool), device=self.device).reshape(N)
        dn = torch.as_tensor(np.asarray(done, dtype=bool), device=self.device).reshape(N) | to
        tv = None
        if bool(to.any()):
            if terminal_obs is None:
                raise ValueError("time-outs need terminal_obs to bootstrap from")
            ids = torch.nonzero(to).squeeze(-1)
            rows = {k: np.asarray(v)[ids.cpu().numpy()] for k, v in terminal_obs.items()}
            tv = torch.zeros(N, len(self.groups), device=self.device)
            tv[ids] = self._values_of(rows, ids)
        self.storage.store_rewards(self.step, r, dn, to, tv, self.cfg.gamma)
        if self.n_student > 0:
            self.hidden[dn[self.n_teacher :]] = 0.0
        self.step += 1

    # ------------------------------------------------------------------------------------------
    # losses (public so that tests can check where each gradient goes)
    def entropy_coef_now(self) -> float:
        c = self.cfg
        if c.entropy_decay_iters == 0:
            return c.entropy_coef_final
        f = min(self.iteration / c.entropy_decay_iters, 1.0)
        return c.entropy_coef + (c.entropy_coef_final - c.entropy_coef) * f

    def ppo_loss(
        self, idx: torch.Tensor, entropy_coef: float | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """PPO loss of the flat sample indices ``idx`` (into the T x N rollout, env = idx % N).

        Student rows use the stored latents (fixed inputs); teacher rows recompute theirs from e_t, h_t.
        """
        cfg, m, st = self.cfg, self.model, self.storage
        ent_c = self.entropy_coef_now() if entropy_coef is None else entropy_coef
        # the same samples with the teacher rows first (every term is a mean over rows): the teacher
        # latents are then computed on a contiguous block, with no masked gather or scatter
        tm = self._is_teacher[idx]
        k = int(tm.sum())
        idx = idx[torch.argsort((~tm).to(torch.int8), stable=True)]
        o = st.flat("proprio")[idx]
        e = st.flat("privileged")[idx]
        h = st.flat("heightmap")[idx] if self.dims.has_heightmap else None
        le = st.flat("latent_e")[idx]
        lh = st.flat("latent_h")[idx]
        if k:
            le_t, lh_t = m.teacher_latents(e[:k], h[:k] if h is not None else None)
            le = torch.cat([le_t, le[k:]])
            if m.latent_h_dim:
                lh = torch.cat([lh_t, lh[k:]])
        mu = m.action_mean(o, le, lh)
        log_std = m.log_std.expand_as(mu)
        logp = _gaussian_log_prob(st.flat("actions")[idx], mu, log_std)
        ratio = torch.exp(logp - st.flat("log_probs")[idx])
        adv = st.flat("advantages")[idx]
        surrogate = -torch.min(adv * ratio, adv * torch.clamp(ratio, 1.0 - cfg.clip, 1.0 + cfg.clip)).mean()
        entropy = (m.log_std + 0.5 + _LOG_SQRT_2PI).sum()
        v = m.values(e, h, le, lh)
        ret = st.flat("returns")[idx]
        if cfg.clip_value_loss:
            v_old = st.flat("values")[idx]
            v_clip = v_old + torch.clamp(v - v_old, -cfg.clip, cfg.clip)
            vloss = torch.max((v - ret).square(), (v_clip - ret).square()).mean(dim=0)
        else:
            vloss = (v - ret).square().mean(dim=0)
        loss = surrogate + cfg.value_coef * vloss.sum() - ent_c * entropy
        with torch.no_grad():
            mu_old, s_old = st.flat("mu")[idx], st.flat("sigma")[idx]
            s_new = torch.exp(log_std)
            kl = (
                (
                    torch.log(s_new / s_old)
                    + (s_old.square() + (mu_old - mu).square()) / (2.0 * s_new.square())
                    - 0.5
                )
                .sum(dim=-1)
                .mean()
            )
        info = {
            "surrogate": surrogate.detach(),
            "entropy": entropy.detach(),
            "kl": kl,
            "value_losses": vloss.detach(),
        }
        return loss, info

    def reconstruction_loss(self, idx: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """L_rec of the MLP estimators on flat rows ``idx`` (student rows only unless ``rec_all_envs``).

        Parts: latent_e, privileged, and (run with a height scan but no depth) latent_h, heightmap.
        The image path's parts come from :meth:`image_reconstruction_loss`.
        """
        m, st = self.model, self.storage
        if not self.cfg.rec_all_envs:
            idx = idx[~self._is_teacher[idx]]
            if idx.numel() == 0:  # a teacher-only run: nothing to regress on
                return torch.zeros((), device=self.device), {}
        hist = st.flat("history")[idx]
        e = st.flat("privileged")[idx]
        # the history-only heightmap estimator learns here; the image path's targets come later
        mlp_h = m.est_h is not None and not m.depth_path
        h = st.flat("heightmap")[idx] if mlp_h else None
        with torch.no_grad():
            le_t, lh_t = m.teacher_latents(e, h)
        le_s = m.student_latent_e(hist)
        parts = {"latent_e": F.mse_loss(le_s, le_t), "privileged": F.mse_loss(m.dec_e(le_s), e)}
        if mlp_h:
            parts |= self._heightmap_parts(l2_normalize(m.est_h(hist)), lh_t, h)
        return self._rec_total(parts), parts

    def _heightmap_parts(
        self, lh_s: torch.Tensor, lh_t: torch.Tensor, h: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        """The heightmap estimator's regressions from its latent ``lh_s`` (..., latent_h) against the
        teacher's ``lh_t`` and the scan ``h`` (..., 441): latent_h, heightmap, latent_h_reencoded
        (the teacher encoder's latent of h_hat against lh_t; a figure only, unless
        ``rec_reencode_coef``), and heightmap_err_cm (a figure)."""
        h_hat = self.model.dec_h(lh_s)
        parts = {"latent_h": F.mse_loss(lh_s, lh_t), "heightmap": F.mse_loss(h_hat, h)}
        with torch.set_grad_enabled(torch.is_grad_enabled() and self.cfg.rec_reencode_coef > 0):
            parts["latent_h_reencoded"] = F.mse_loss(self.model.teacher_h_latent(h_hat), lh_t)
        with torch.no_grad():
            parts["heightmap_err_cm"] = self._height_err_cm(h_hat, h)
        return parts

    def _rec_total(self, parts: dict[str, torch.Tensor]) -> torch.Tensor:
        """L_rec: rec_coef x the sum of the regressions in ``parts`` (latent_h_reencoded weighted by
        ``rec_reencode_coef``; heightmap_err_cm is a figure)."""
        weights = {"heightmap_err_cm": 0.0, "latent_h_reencoded": self.cfg.rec_reencode_coef}
        return self.cfg.rec_coef * sum(weights.get(k, 1.0) * v for k, v in parts.items())

    def _height_err_cm(self, h_hat_n: torch.Tensor, h_n: torch.Tensor) -> torch.Tensor:
        scale = self.model.norm_heightmap.scale()
        return torch.sqrt(((h_hat_n - h_n) * scale).square().mean()) * 100.0

    def _chunk_image_features(self, frames: torch.Tensor) -> torch.Tensor:
        """CNN features (L * B, depth_feature) of frames (L, B, rows, cols), steps first.

        A frame equal to the same env's frame one step earlier (a 30 Hz frame held over a 50 Hz
        step) reuses its features instead of a second CNN pass; the gradient of the shared features
        is the sum over their uses, exactly what separate passes would give.
        """
        L, B = frames.shape[:2]
        held = torch.zeros(L, B, dtype=torch.bool, device=frames.device)
        held[1:] = (frames[1:] == frames[:-1]).flatten(2).all(dim=2)
        steps = torch.arange(L, device=frames.device).unsqueeze(1).expand(L, B)
        source = torch.cummax(torch.where(held, 0, steps), dim=0).values  # step of the frame shown
        fresh = torch.nonzero(~held.reshape(-1)).squeeze(-1)  # flat (step * B + env) of new frames
        slot = torch.empty(L * B, dtype=torch.long, device=frames.device)
        slot[fresh] = torch.arange(fresh.numel(), device=frames.device)
        envs = torch.arange(B, device=frames.device)
        unique = self.model.est_h.cnn(frames.reshape(L * B, *frames.shape[2:])[fresh])
        return unique[slot[(source * B + envs).reshape(-1)]]

    def image_reconstruction_loss(
        self, start: int, length: int, hidden: torch.Tensor
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor], torch.Tensor]:
        """L_rec of the image path (latent_h, heightmap) over steps [start, start + length) of the
        ``rec_env_ids`` envs, starting from GRU state ``hidden`` (B, gru_hidden).

        Returns (loss, parts, hidden at the end of the chunk, zeroed where the last step was a done).
        """
        m, st = self.model, self.storage
        est = m.est_h
        ids = st.rec_env_ids
        sl = slice(start, start + length)
        hist = st.history[sl, ids]  # (L, B, HP)
        hmap = st.heightmap[sl, ids]
        dones = st.dones[sl, ids]
        L, B = hist.shape[0], hist.shape[1]
        with torch.no_grad():
            lh_t = m.teacher_h_latent(hmap)
        frames = st.depth[sl]
        feats = est.features(hist.reshape(L * B, -1), None, self._chunk_image_features(frames))
        feats = feats.reshape(L, B, -1)
        hs = []
        h = hidden
        for k in range(L):
            h = est.gru(feats[k], h)
            hs.append(h)
            h = h * (1.0 - dones[k]).unsqueeze(-1)
        parts = self._heightmap_parts(est.latent(torch.stack(hs)), lh_t, hmap)
        return self._rec_total(parts), parts, h

    # ------------------------------------------------------------------------------------------
    # update
    def _precision(self) -> contextlib.AbstractContextManager:
        """The update's arithmetic: nothing for fp32, bfloat16 autocast for bf16."""
        if self.cfg.precision == "bf16":
            return torch.autocast(self.device.type, dtype=torch.bfloat16)
        return contextlib.nullcontext()

    def _adapt_lr(self, kl: float) -> None:
        c = self.cfg
        if c.desired_kl is None:
            return
        if kl > 2.0 * c.desired_kl:
            self.lr = max(c.lr_min, self.lr / c.lr_factor)
        elif 0.0 < kl < 0.5 * c.desired_kl:
            self.lr = min(c.lr_max, self.lr * c.lr_factor)
        for g in self.opt_ppo.param_groups:
            g["lr"] = self.lr

    def update(self, last_obs: Mapping[str, np.ndarray]) -> dict[str, float]:
        """PPO epochs and the reconstruction losses on the full rollout; returns statistics.

        last_obs: the observation the env returned after the T-th step (the one the next ``act`` gets);
        its values bootstrap the returns of envs still running. Keys of the returned dict:
        ``value_loss/<group>``, ``surrogate_loss``, ``entropy``, ``kl``, ``lr``, ``action_std``,
        ``entropy_coef``, ``rec_latent_e``, ``rec_privileged``, and with a height scan ``rec_latent_h``,
        ``rec_heightmap``, ``rec_latent_h_reencoded``, ``heightmap_err_cm`` (RMS of h_hat - h in cm; the
        image path's first pass),
        ``student_forced`` (1 while ``student_warmup`` holds), ``iteration`` (completed
        updates) and ``learn_s`` (wall time of this call).
        """
        t0 = time.perf_counter()
        cfg, st, m = self.cfg, self.storage, self.model
        if self.step != cfg.num_steps_per_env:
            raise RuntimeError(f"update() needs a full rollout: {self.step} of {cfg.num_steps_per_env} steps")
        last_values = self._values_of(last_obs, torch.arange(self.num_envs, device=self.device))
        with torch.no_grad():
            st.compute_returns(last_values, cfg.gamma, cfg.lam, self.weights)
        ent_c = self.entropy_coef_now()
        n_samples = cfg.num_steps_per_env * self.num_envs
        acc: dict[str, float] = {}
        counts: dict[str, int] = {}

        def add(key: str, value: torch.Tensor | float) -> None:
            acc[key] = acc.get(key, 0.0) + float(value.detach() if torch.is_tensor(value) else value)
            counts[key] = counts.get(key, 0) + 1

        ppo_params = m.ppo_parameters()
        rec_params = m.estimator_parameters()
        for _ in range(cfg.num_epochs):
            perm = torch.randperm(n_samples, generator=self.generator, device=self.device)
            for idx in torch.tensor_split(perm, cfg.num_minibatches):
                with self._precision():
                    loss, info = self.ppo_loss(idx, ent_c)
                self._adapt_lr(float(info["kl"]))
                self.opt_ppo.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(ppo_params, cfg.max_grad_norm)
                self.opt_ppo.step()
                add("surrogate_loss", info["surrogate"])
                add("entropy", info["entropy"])
                add("kl", info["kl"])
                for g, vl in zip(self.groups, info["value_losses"], strict=True):
                    add(f"value_loss/{g}", vl)
                with self._precision():
                    rec, parts = self.reconstruction_loss(idx)
                if rec.requires_grad:
                    self.opt_rec.zero_grad(set_to_none=True)
                    rec.backward()
                    torch.nn.utils.clip_grad_norm_(rec_params, cfg.max_grad_norm)
                    self.opt_rec.step()
                for k, v in parts.items():
                    add(k if k == "heightmap_err_cm" else f"rec_{k}", v)
        if self.rec_envs > 0:
            img: dict[str, float] = {}
            for epoch in range(cfg.rec_epochs):
                hidden = st.hidden0.clone()
                for s in range(0, cfg.num_steps_per_env, cfg.tbptt):
                    length = min(cfg.tbptt, cfg.num_steps_per_env - s)
                    with self._precision():
                        loss, parts, hidden = self.image_reconstruction_loss(s, length, hidden.detach())
                    self.opt_rec.zero_grad(set_to_none=True)
                    loss.backward()
                    torch.nn.utils.clip_grad_norm_(rec_params, cfg.max_grad_norm)
                    self.opt_rec.step()
                    if epoch == 0:  # the first pass meets these frames before training on them
                        for k, v in parts.items():
                            img[k] = img.get(k, 0.0) + float(v.detach()) * length
            for k, v in img.items():  # image-path figures replace per-minibatch ones
                key = k if k == "heightmap_err_cm" else f"rec_{k}"
                acc[key], counts[key] = v / cfg.num_steps_per_env, 1
        stats = {k: acc[k] / counts[k] for k in acc}
        stats["lr"] = self.lr
        stats["entropy_coef"] = ent_c
        stats["action_std"] = float(torch.exp(m.log_std.detach()).mean())
        stats["student_forced"] = float(self.n_student > 0 and self.student_forced)
        self.iteration += 1
        self.step = 0
        self._drop_image_cache()
        stats["iteration"] = float(self.iteration)
        stats["learn_s"] = time.perf_counter() - t0
        return stats

    # ------------------------------------------------------------------------------------------
    # student inference and export
    def policy_for_export(self) -> StudentPolicy:
        """A CPU copy of the student path in eval mode, detached from further training (see
        :class:`StudentPolicy` for the forward signature)."""
        pol = copy.deepcopy(self._student).to("cpu").eval()
        for p in pol.parameters():
            p.requires_grad_(False)
        return pol

    @torch.no_grad()
    def student_step(
        self, obs: Mapping[str, np.ndarray], hidden: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Deterministic student action for B rows: obs holds ``history`` (B, H*P) and, when the run has
        depth, ``depth`` (B, rows, cols). hidden: (B, gru_hidden) or None (zeros: episode start).
        Returns numpy (action_mean, hidden_next, h_hat in m, e_hat); normalisers are not updated."""
        hist = torch.as_tensor(np.asarray(obs["history"], dtype=np.float32), device=self.device)
        B = hist.shape[0]
        if self.dims.depth_hw is not None:
            depth = torch.as_tensor(np.asarray(obs["depth"], dtype=np.float32), device=self.device)
        else:
            depth = torch.zeros(B, 1, 1, device=self.device)
        if hidden is None:
            h = torch.zeros(B, self.cfg.gru_hidden, device=self.device)
        else:
            h = torch.as_tensor(np.asarray(hidden, dtype=np.float32), device=self.device)
        outs = self._student(hist, depth, h)
        return tuple(x.cpu().numpy() for x in outs)  # type: ignore[return-value]

    # ------------------------------------------------------------------------------------------
    # checkpoints
    def state_dict(self) -> dict:
        """Tensors and plain python values only (loadable with ``torch.load(weights_only=True)``)."""
        return {
            "format": CHECKPOINT_FORMAT,
            "dims": self.dims.to_dict(),
            "groups": list(self.groups),
            "config": self.cfg.to_dict(),
            "num_envs": self.num_envs,
            "n_teacher": self.n_teacher,
            "seed": self.seed,
            "model": self.model.state_dict(),
            "optim_ppo": self.opt_ppo.state_dict(),
            "optim_rec": self.opt_rec.state_dict(),
            "lr": float(self.lr),
            "iteration": int(self.iteration),
            "entropy_coef": float(self.entropy_coef_now()),
            "generator": self.generator.get_state(),
            "hidden": self.hidden.detach().cpu().clone(),
        }

    def load_state_dict(self, sd: Mapping) -> None:
        """Restore a :meth:`state_dict`. Any partial rollout is discarded. GRU states and the sampling
        generator are restored only when the env count matches (else they start fresh); a generator
        saved on another kind of device is reseeded from the seed and the iteration."""
        if sd.get("format") != CHECKPOINT_FORMAT:
            raise ValueError(f"not a learner checkpoint (format {sd.get('format')!r})")
        if ObsDims.from_dict(sd["dims"]) != self.dims:
            raise ValueError(f"checkpoint observation dims {sd['dims']} differ from {self.dims.to_dict()}")
        if tuple(sd["groups"]) != self.groups:
            raise ValueError(f"checkpoint reward groups {sd['groups']} differ from {list(self.groups)}")
        self.model.load_state_dict(sd["model"])
        for opt, key in ((self.opt_ppo, "optim_ppo"), (self.opt_rec, "optim_rec")):
            opt.load_state_dict(sd[key])
            _use_fused_adam(opt)
        self.lr = float(sd["lr"])
        for g in self.opt_ppo.param_groups:
            g["lr"] = self.lr
        self.iteration = int(sd["iteration"])
        same_envs = int(sd["num_envs"]) == self.num_envs and int(sd["n_teacher"]) == self.n_teacher
        if same_envs:
            self.hidden.copy_(sd["hidden"].to(self.device))
            try:  # a generator state saved on another kind of device does not fit this one
                self.generator.set_state(sd["generator"])
            except RuntimeError:
                self.generator.manual_seed(self.seed + self.iteration)
        else:
            self.hidden.zero_()
        self.step = 0
        self._drop_image_cache()

    @classmethod
    def from_state_dict(
        cls, sd: Mapping, num_envs: int | None = None, device: str | torch.device = "cpu"
    ) -> VisionCTSLearner:
        """Build a learner from a checkpoint's own dims, groups and config, then load it."""
        learner = cls(
            ObsDims.from_dict(sd["dims"]),
            int(num_envs or sd["num_envs"]),
            tuple(sd["groups"]),
            LearnerConfig.from_dict(sd["config"]),
            device=device,
            seed=int(sd.get("seed", 0)),
        )
        learner.load_state_dict(sd)
        return learner
