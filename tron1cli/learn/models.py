"""Vision-CTS networks: teacher encoders, student estimators, the shared policy and one critic per
reward group (paper section IV).

Latents are L2-normalised (CTS). With ``l^e`` the privileged latent and ``l^h`` the heightmap latent:

- teacher rows:  l^e = enc_e(e_t),            l^h = enc_h(h_t)
- student rows:  l^e = est_e(o^H_t),          l^h = GRU([mlp(o^H_t), cnn(d_t)]) when the run has depth,
                 MLP(o^H_t) when it has a height scan but no depth, nothing when it has neither
- policy:        a_mean = actor([o_t, l^e, l^h]),  learned state-independent log-std
- critic g:      V_g = critic_g([e_t, h_t, l^e, l^h])

Every input is normalised by the model's own running normalisers (``norm_*``) before it reaches a
network; the decoders predict normalised e_t and h_t (``*.inverse`` maps them back to physical units).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from tron1cli.learn.config import LearnerConfig, ObsDims
from tron1cli.learn.normalizer import RunningNormalizer


class _ExpELUFunction(torch.autograd.Function):
    """ELU (alpha 1) as max(x, e - 1) with e = exp(min(x, 0)); its derivative is e itself."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        e = torch.clamp(x, max=0.0).exp_()
        ctx.save_for_backward(e)
        return torch.maximum(x, e - 1.0)

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (e,) = ctx.saved_tensors
        return grad * e


class ELU(nn.Module):
    """ELU with alpha 1, the same function and gradient as ``nn.ELU`` to float rounding, faster on CPU.

    torch's CPU ELU evaluates expm1, which costs 3-4x an exp on AVX2; ELU(x) = max(x, exp(min(x, 0))
    - 1) needs only the exp (e^x - 1 >= x, with equality at 0), and the backward pass multiplies by
    the saved exp(min(x, 0)) instead of re-deriving it. Measured on the 2-core AVX2 machine on a
    3072 x 256 minibatch activation: forward and backward 6.6 ms -> 3.6 ms. An ONNX export or a
    trace gets ``F.elu`` (one Elu node).
    """

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if torch.jit.is_tracing() or torch.jit.is_scripting() or torch.onnx.is_in_onnx_export():
            return F.elu(x)
        if torch.is_grad_enabled() and x.requires_grad:
            return _ExpELUFunction.apply(x)
        return torch.maximum(x, torch.clamp(x, max=0.0).exp_().sub_(1.0))


_ACT = {"elu": ELU, "relu": nn.ReLU, "tanh": nn.Tanh}


def mlp(
    in_dim: int, hidden: tuple[int, ...], out_dim: int, activation: str = "elu", out_gain: float | None = None
) -> nn.Sequential:
    """in -> hidden... (activation after each) -> out (linear). out_gain scales the last layer's init."""
    layers: list[nn.Module] = []
    d = in_dim
    for h in hidden:
        layers += [nn.Linear(d, h), _ACT[activation]()]
        d = h
    last = nn.Linear(d, out_dim)
    if out_gain is not None:
        with torch.no_grad():
            last.weight.mul_(out_gain)
            last.bias.zero_()
    layers.append(last)
    return nn.Sequential(*layers)


def l2_normalize(x: torch.Tensor) -> torch.Tensor:
    """Unit L2 norm along the last dimension (exportable: no F.normalize special cases)."""
    return x / torch.clamp(torch.linalg.vector_norm(x, dim=-1, keepdim=True), min=1e-6)


class SplitInputMLP(nn.Module):
    """An MLP on [obs, lat] whose first layer is split as W_o obs + W_l lat (the same function class).

    Used for the critics: obs (e_t, h_t: ~500 wide) never needs an input gradient, lat (the teacher
    latents) does; the split keeps autograd from computing the 500-wide input gradient (about 25 % of
    a PPO minibatch with a height scan).
    """

    def __init__(
        self, obs_dim: int, lat_dim: int, hidden: tuple[int, ...], out_dim: int, activation: str = "elu"
    ) -> None:
        super().__init__()
        first = hidden[0] if hidden else out_dim
        self.obs_in = nn.Linear(obs_dim, first)
        self.lat_in = nn.Linear(lat_dim, first, bias=False) if lat_dim > 0 else None
        if hidden:
            self.rest = nn.Sequential(_ACT[activation](), mlp(first, tuple(hidden[1:]), out_dim, activation))
        else:
            self.rest = nn.Identity()

    def forward(self, obs: torch.Tensor, lat: torch.Tensor) -> torch.Tensor:
        x = self.obs_in(obs)
        if self.lat_in is not None:
            w = self.lat_in.weight
            if x.dim() == 2 and x.dtype == lat.dtype == w.dtype:  # fp32: x += lat W_l^T in the
                x = x.addmm_(lat, w.t())  # product itself, no separate pass over x for the sum
            else:  # batched inputs, or autocast's bf16 x
                x = x + self.lat_in(lat)
        return self.rest(x)


class GRUCell(nn.Module):
    """GRU cell written with two linear layers (same equations as torch.nn.GRUCell).

    Written out so that it exports to plain ONNX MatMul / Sigmoid / Tanh ops.
    """

    def __init__(self, input_size: int, hidden_size: int) -> None:
        super().__init__()
        self.hidden_size = hidden_size
        self.ih = nn.Linear(input_size, 3 * hidden_size)
        self.hh = nn.Linear(hidden_size, 3 * hidden_size)
        bound = 1.0 / math.sqrt(hidden_size)
        for p in self.parameters():
            nn.init.uniform_(p, -bound, bound)

    def forward(self, x: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        gi = self.ih(x)
        gh = self.hh(h)
        i_r, i_z, i_n = gi.chunk(3, dim=-1)
        h_r, h_z, h_n = gh.chunk(3, dim=-1)
        r = torch.sigmoid(i_r + h_r)
        z = torch.sigmoid(i_z + h_z)
        n = torch.tanh(i_n + r * h_n)
        return (1.0 - z) * n + z * h


def _conv_out(size: int, kernel: int, stride: int, pad: int) -> int:
    return (size + 2 * pad - kernel) // stride + 1


class DepthCNN(nn.Module):
    """Three stride-2 convolutions and a linear layer: (B, rows, cols) depth in m -> (B, out).

    Depth is clamped to [0, depth_max] and scaled to [0, 1] here, so an export carries the scaling.
    On 60 x 80 with channels (8, 16, 32): 30x40x8 -> 15x20x16 -> 8x10x32 -> out; about 1 M
    multiply-adds per image.
    """

    def __init__(
        self,
        hw: tuple[int, int],
        channels: tuple[int, int, int],
        out: int,
        depth_max: float,
        activation: str = "elu",
    ) -> None:
        super().__init__()
        self.depth_max = float(depth_max)
        c1, c2, c3 = channels
        act = _ACT[activation]
        self.conv = nn.Sequential(
            nn.Conv2d(1, c1, 5, stride=2, padding=2),
            act(),
            nn.Conv2d(c1, c2, 3, stride=2, padding=1),
            act(),
            nn.Conv2d(c2, c3, 3, stride=2, padding=1),
            act(),
        )
        r, c = hw
        r, c = _conv_out(r, 5, 2, 2), _conv_out(c, 5, 2, 2)
        r, c = _conv_out(r, 3, 2, 1), _conv_out(c, 3, 2, 1)
        r, c = _conv_out(r, 3, 2, 1), _conv_out(c, 3, 2, 1)
        self.head = nn.Sequential(nn.Linear(c3 * r * c, out), act())

    def forward(self, depth: torch.Tensor) -> torch.Tensor:
        x = torch.clamp(depth, 0.0, self.depth_max) * (1.0 / self.depth_max)
        x = self.conv(x.unsqueeze(1))
        return self.head(x.flatten(1))


class DepthHeightEstimator(nn.Module):
    """Student heightmap encoder with depth: [MLP(o^H_t), CNN(d_t)] -> GRU -> linear -> l^{s,h}."""

    def __init__(self, history: int, dims: ObsDims, cfg: LearnerConfig) -> None:
        super().__init__()
        assert dims.depth_hw is not None
        f = cfg.depth_feature
        self.hist_mlp = mlp(history, cfg.encoder_hidden, f, cfg.activation)
        self.hist_act = _ACT[cfg.activation]()
        self.cnn = DepthCNN(dims.depth_hw, cfg.cnn_channels, f, cfg.depth_max, cfg.activation)
        self.gru = GRUCell(2 * f, cfg.gru_hidden)
        self.out = nn.Linear(cfg.gru_hidden, cfg.latent_h)

    def features(
        self,
        hist_n: torch.Tensor,
        depth: torch.Tensor | None,
        image_features: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """(B, H*P), (B, rows, cols) -> (B, 2 * depth_feature), the GRU input.

        image_features: ``cnn(depth)`` (B, depth_feature) when the caller already has it (a frame
        held over from the previous step); ``depth`` is then not looked at.
        """
        img = self.cnn(depth) if image_features is None else image_features
        return torch.cat([self.hist_act(self.hist_mlp(hist_n)), img], dim=-1)

    def latent(self, hidden: torch.Tensor) -> torch.Tensor:
        return l2_normalize(self.out(hidden))

    def step(
        self,
        hist_n: torch.Tensor,
        depth: torch.Tensor,
        hidden: torch.Tensor,
        image_features: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One policy step: -> (l^{s,h}, hidden_next); image_features as in :meth:`features`."""
        h = self.gru(self.features(hist_n, depth, image_features), hidden)
        return self.latent(h), h


class VisionCTS(nn.Module):
    """All networks of Vision-CTS plus the running observation normalisers.

    groups: reward-group names, one critic each (``critics[g]``).
    Parameter sets: :meth:`ppo_parameters` (teacher encoders, policy, log-std, critics: trained by PPO)
    and :meth:`estimator_parameters` (student estimators: trained by the reconstruction loss only).
    """

    def __init__(self, dims: ObsDims, groups: tuple[str, ...], cfg: LearnerConfig) -> None:
        super().__init__()
        self.dims = dims
        self.groups = tuple(groups)
        act = cfg.activation
        P, HP, E, Hm, A = dims.proprio, dims.history, dims.privileged, dims.heightmap, dims.action
        Le = cfg.latent_e
        Lh = cfg.latent_h if dims.has_heightmap else 0
        self.latent_e_dim, self.latent_h_dim = Le, Lh
        self.gru_hidden = cfg.gru_hidden
        self.reencode_h = bool(cfg.reencode_h)
        on, clip = cfg.obs_normalization, cfg.normalizer_clip
        self.norm_proprio = RunningNormalizer(P, clip=clip, enabled=on)
        self.norm_history = RunningNormalizer(HP, clip=clip, enabled=on)
        self.norm_privileged = RunningNormalizer(E, clip=clip, enabled=on)
        self.norm_heightmap = RunningNormalizer(max(Hm, 1), shared=True, clip=clip, enabled=on)

        # teacher encoders (PPO gradient through the teacher rows)
        self.teacher_e = mlp(E, cfg.encoder_hidden, Le, act)
        self.teacher_h = mlp(Hm, cfg.heightmap_encoder_hidden, Lh, act) if Lh else None
        # student estimators (reconstruction loss only)
        self.est_e = mlp(HP, cfg.encoder_hidden, Le, act)
        self.dec_e = mlp(Le, cfg.decoder_hidden, E, act)
        self.est_h: nn.Module | None = None
        self.dec_h: nn.Module | None = None
        if Lh:
            if dims.has_depth:
                self.est_h = DepthHeightEstimator(HP, dims, cfg)
            else:
                self.est_h = mlp(HP, cfg.heightmap_encoder_hidden, Lh, act)
            self.dec_h = mlp(Lh, cfg.decoder_hidden, Hm, act)
        # shared policy and critics
        self.actor = mlp(P + Le + Lh, cfg.actor_hidden, A, act, out_gain=0.01)
        self.log_std = nn.Parameter(torch.full((A,), math.log(cfg.init_noise_std)))
        self.critics = nn.ModuleDict(
            {g: SplitInputMLP(E + Hm, Le + Lh, cfg.critic_hidden, 1, act) for g in self.groups}
        )

    # ---- parameter sets -------------------------------------------------------------------
    def ppo_parameters(self) -> list[nn.Parameter]:
        mods = [self.teacher_e, self.teacher_h, self.actor, self.critics]
        params = [p for m in mods if m is not None for p in m.parameters()]
        return params + [self.log_std]

    def estimator_parameters(self) -> list[nn.Parameter]:
        mods = [self.est_e, self.dec_e, self.est_h, self.dec_h]
        return [p for m in mods if m is not None for p in m.parameters()]

    @property
    def depth_path(self) -> bool:
        return isinstance(self.est_h, DepthHeightEstimator)

    # ---- observations -----------------------------------------------------------------------
    def update_normalizers(self, obs: dict[str, torch.Tensor]) -> None:
        self.norm_proprio.update(obs["proprio"])
        self.norm_history.update(obs["history"])
        self.norm_privileged.update(obs["privileged"])
        if self.latent_h_dim:
            self.norm_heightmap.update(obs["heightmap"])

    def normalize(self, obs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Raw observation groups -> normalised ones (depth passes through; the CNN scales it)."""
        out = {
            "proprio": self.norm_proprio(obs["proprio"]),
            "history": self.norm_history(obs["history"]),
            "privileged": self.norm_privileged(obs["privileged"]),
        }
        if self.latent_h_dim:
            out["heightmap"] = self.norm_heightmap(obs["heightmap"])
        if "depth" in obs:
            out["depth"] = obs["depth"]
        return out

    # ---- latents ----------------------------------------------------------------------------
    def _empty(self, x: torch.Tensor) -> torch.Tensor:
        return x[:, :0]

    def teacher_latents(
        self, e_n: torch.Tensor, h_n: torch.Tensor | None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        le = l2_normalize(self.teacher_e(e_n))
        if self.teacher_h is None or h_n is None:
            return le, self._empty(e_n)
        return le, self.teacher_h_latent(h_n)

    def teacher_h_latent(self, h_n: torch.Tensor) -> torch.Tensor:
        """The teacher encoder's heightmap latent of a (normalised) scan ``h_n`` (..., 441)."""
        return l2_normalize(self.teacher_h(h_n))

    def student_latent_e(self, hist_n: torch.Tensor) -> torch.Tensor:
        return l2_normalize(self.est_e(hist_n))

    def student_latents(
        self,
        hist_n: torch.Tensor,
        depth: torch.Tensor | None,
        hidden: torch.Tensor,
        image_features: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """-> (l^{s,e}, l^{s,h}, hidden_next); hidden passes through unchanged without depth.

        image_features: the depth CNN's output for ``depth`` when the caller has it already.
        """
        le = self.student_latent_e(hist_n)
        if self.est_h is None:
            return le, self._empty(hist_n), hidden
        if isinstance(self.est_h, DepthHeightEstimator):
            assert depth is not None
            lh, h = self.est_h.step(hist_n, depth, hidden, image_features)
            return le, self.policy_h_latent(lh), h
        return le, self.policy_h_latent(l2_normalize(self.est_h(hist_n))), hidden

    def policy_h_latent(self, lh_s: torch.Tensor) -> torch.Tensor:
        """The heightmap latent the policy reads for a student: its estimator's ``lh_s``, or with
        ``reencode_h`` :meth:`reencoded_h` of it."""
        return self.reencoded_h(lh_s) if self.reencode_h else lh_s

    def reencoded_h(self, lh_s: torch.Tensor) -> torch.Tensor:
        """The teacher encoder's latent of the student's reconstruction, l2(enc^{t,h}(dec_h(lh_s)))."""
        return self.teacher_h_latent(self.dec_h(lh_s))

    # ---- heads ------------------------------------------------------------------------------
    def action_mean(self, o_n: torch.Tensor, le: torch.Tensor, lh: torch.Tensor) -> torch.Tensor:
        return self.actor(torch.cat([o_n, le, lh], dim=-1))

    def values(
        self, e_n: torch.Tensor, h_n: torch.Tensor | None, le: torch.Tensor, lh: torch.Tensor
    ) -> torch.Tensor:
        """-> (B, G), one column per reward group in ``groups`` order."""
        obs = torch.cat([e_n, h_n], dim=-1) if (self.latent_h_dim and h_n is not None) else e_n
        lat = torch.cat([le, lh], dim=-1)
        return torch.cat([self.critics[g](obs, lat) for g in self.groups], dim=-1)


class StudentPolicy(nn.Module):
    """The deployable student: ``forward(history, depth, hidden) -> (action_mean, hidden_next, h_hat,
    e_hat)``, deterministic, with the observation normalisation baked in.

    history: (B, H*P) raw o^H_t, oldest first; the current o_t is its last P entries.
    depth: (B, rows, cols) depth in m; when the run has no depth image any float tensor of shape
        (B, r, c) is accepted and ignored (e.g. zeros (B, 1, 1)): the signature stays fixed and an ONNX
        export keeps the input.
    hidden: (B, gru_hidden) GRU state (zeros at an episode start); without depth it is returned unchanged.
    Returns action_mean (B, A) (the policy's mean: joint position offsets before the action scale),
    hidden_next (B, gru_hidden), h_hat (B, heightmap) in m relative to the base ((B, 0) when the run
    has no height scan: a zero-width slice, which ONNX represents), e_hat (B, E) in e_t's units.
    """

    def __init__(self, model: VisionCTS) -> None:
        super().__init__()
        self.proprio = model.dims.proprio
        self.norm_proprio = model.norm_proprio
        self.norm_history = model.norm_history
        self.norm_privileged = model.norm_privileged
        self.norm_heightmap = model.norm_heightmap
        self.est_e = model.est_e
        self.dec_e = model.dec_e
        self.est_h = model.est_h
        self.dec_h = model.dec_h
        self.actor = model.actor
        self.depth_path = model.depth_path
        self.teacher_h = model.teacher_h if model.reencode_h else None

    def forward(
        self, history: torch.Tensor, depth: torch.Tensor, hidden: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        hist_n = self.norm_history(history)
        o_n = self.norm_proprio(history[:, history.shape[1] - self.proprio :])
        le = l2_normalize(self.est_e(hist_n))
        e_hat = self.norm_privileged.inverse(self.dec_e(le))
        if self.est_h is None or self.dec_h is None:
            lh = history[:, :0]
            h_hat = history[:, :0]
            hidden_next = hidden
        else:
            if self.depth_path:
                lh, hidden_next = self.est_h.step(hist_n, depth, hidden)
            else:
                lh = l2_normalize(self.est_h(hist_n))
                hidden_next = hidden
            h_hat_n = self.dec_h(lh)
            h_hat = self.norm_heightmap.inverse(h_hat_n)
            if self.teacher_h is not None:  # reencode_h: the policy reads enc^{t,h}(h_hat)
                lh = l2_normalize(self.teacher_h(h_hat_n))
        parts = [o_n, le, lh]
        if not self.depth_path:
            # a zero-width slice of the unused depth input keeps it in an exported graph (the
            # TorchScript ONNX exporter drops unused inputs) without touching any value
            parts.append(depth.reshape(depth.shape[0], -1)[:, :0])
        mean = self.actor(torch.cat(parts, dim=-1))
        return mean, hidden_next, h_hat, e_hat
