"""Rollout buffer (T x N) with one reward, value and return column per reward group.

Each group g gets its own GAE lambda-return against its own critic V_g; the advantage PPO uses is
``sum_g w_g * (A_g - mean(A_g)) / std(A_g)`` with the mean and std taken over the whole T x N batch
(multi-critic, Zargarbashi et al. 2024).
"""

from __future__ import annotations

import torch

from tron1cli.learn.config import ObsDims


def compute_gae(
    rewards: torch.Tensor,
    values: torch.Tensor,
    dones: torch.Tensor,
    last_values: torch.Tensor,
    gamma: float,
    lam: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """GAE(lambda) for every column at once.

    rewards, values: (T, N, G); dones: (T, N) (1 where the episode ended at that step; a time-out's
    bootstrap must already be in its reward); last_values: (N, G), V of the observation after step T-1.
    Returns (advantages, returns), both (T, N, G), returns = advantages + values.
    """
    T = rewards.shape[0]
    adv = torch.zeros_like(rewards)
    running = torch.zeros_like(last_values)
    next_values = last_values
    for t in reversed(range(T)):
        not_done = (1.0 - dones[t].to(rewards.dtype)).unsqueeze(-1)
        delta = rewards[t] + gamma * next_values * not_done - values[t]
        running = delta + gamma * lam * not_done * running
        adv[t] = running
        next_values = values[t]
    return adv, adv + values


def normalize_advantages(adv: torch.Tensor, weights: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """adv (..., G), weights (G,) -> (combined (...), per-group normalised (..., G)).

    Each group is normalised over all leading dimensions to zero mean and unit (unbiased) std.
    """
    a64 = adv.to(torch.float64)  # a group with a large mean and a tiny spread keeps its precision
    flat = a64.reshape(-1, adv.shape[-1])
    mean = flat.mean(dim=0)
    std = flat.std(dim=0) if flat.shape[0] > 1 else torch.ones_like(mean)
    normed = (a64 - mean) / (std + 1e-8)
    combined = (normed * weights.to(torch.float64)).sum(dim=-1)
    return combined.to(adv.dtype), normed.to(adv.dtype)


class RolloutStorage:
    """Preallocated float32 buffers for one iteration's rollout.

    Per step and env: the normalised policy inputs actually used (o_t, l^e, l^h: for student rows the
    student latents computed at collection, for teacher rows the teacher latents, which the update
    recomputes), the normalised critic inputs (e_t, h_t), o^H_t (for the reconstruction loss), actions,
    log-probs, action means and stds, per-group values and rewards, dones. For the image path: the
    depth images of ``rec_env_ids`` (student envs sampled at the start of the rollout) and their GRU
    states at that start.
    """

    def __init__(
        self,
        T: int,
        N: int,
        dims: ObsDims,
        latent_e: int,
        latent_h: int,
        num_groups: int,
        rec_envs: int,
        gru_hidden: int,
        device: torch.device | str = "cpu",
    ) -> None:
        f32 = dict(dtype=torch.float32, device=device)
        self.T, self.N, self.G = T, N, num_groups
        self.proprio = torch.zeros(T, N, dims.proprio, **f32)
        self.history = torch.zeros(T, N, dims.history, **f32)
        self.privileged = torch.zeros(T, N, dims.privileged, **f32)
        self.heightmap = torch.zeros(T, N, dims.heightmap, **f32)
        self.latent_e = torch.zeros(T, N, latent_e, **f32)
        self.latent_h = torch.zeros(T, N, latent_h, **f32)
        self.actions = torch.zeros(T, N, dims.action, **f32)
        self.log_probs = torch.zeros(T, N, **f32)
        self.mu = torch.zeros(T, N, dims.action, **f32)
        self.sigma = torch.zeros(T, N, dims.action, **f32)
        self.values = torch.zeros(T, N, num_groups, **f32)
        self.rewards = torch.zeros(T, N, num_groups, **f32)
        self.dones = torch.zeros(T, N, **f32)
        self.returns = torch.zeros(T, N, num_groups, **f32)
        self.group_advantages = torch.zeros(T, N, num_groups, **f32)
        self.advantages = torch.zeros(T, N, **f32)
        self.rec_env_ids = torch.zeros(rec_envs, dtype=torch.long, device=device)
        if dims.depth_hw is not None and rec_envs > 0:
            self.depth = torch.zeros(T, rec_envs, *dims.depth_hw, **f32)
            self.hidden0 = torch.zeros(rec_envs, gru_hidden, **f32)
        else:
            self.depth = None
            self.hidden0 = None

    def store_rewards(
        self,
        t: int,
        rewards: torch.Tensor,
        dones: torch.Tensor,
        time_outs: torch.Tensor,
        terminal_values: torch.Tensor | None,
        gamma: float,
    ) -> None:
        """rewards (N, G); dones, time_outs (N,) bool; terminal_values (N, G) = V_g(observation before
        the reset), used only where time_outs: reward += gamma * V_g(terminal)."""
        r = rewards.to(torch.float32)
        if terminal_values is not None:
            r = r + gamma * terminal_values * time_outs.to(torch.float32).unsqueeze(-1)
        self.rewards[t].copy_(r)
        self.dones[t].copy_(dones.to(torch.float32))

    def compute_returns(
        self, last_values: torch.Tensor, gamma: float, lam: float, weights: torch.Tensor
    ) -> None:
        adv, ret = compute_gae(self.rewards, self.values, self.dones, last_values, gamma, lam)
        self.returns.copy_(ret)
        combined, normed = normalize_advantages(adv, weights)
        self.group_advantages.copy_(normed)
        self.advantages.copy_(combined)

    def flat(self, name: str) -> torch.Tensor:
        """A (T, N, ...) buffer viewed as (T * N, ...); flat index i is env i % N at step i // N."""
        x = getattr(self, name)
        return x.reshape(self.T * self.N, *x.shape[2:])
