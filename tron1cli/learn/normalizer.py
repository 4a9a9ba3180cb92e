"""Running mean / standard-deviation observation normaliser.

Statistics live in torch buffers (so they travel with ``state_dict`` and are baked into an export)
and change only through :meth:`RunningNormalizer.update`, which the learner calls on collected
observations. ``forward`` maps ``x`` to ``clip((x - mean) / sqrt(var + eps), -clip, clip)``.
"""

from __future__ import annotations

import torch
from torch import nn


class RunningNormalizer(nn.Module):
    """Normalise features by running statistics.

    size: feature width. shared: one mean / variance for all features (used for the height scan, whose
    points share one scale, so a flat-ground start does not give near-zero per-point variances).
    clip: output clip in sigmas. eps: added to the variance. enabled: False makes it the identity.
    """

    def __init__(
        self, size: int, *, shared: bool = False, clip: float = 5.0, eps: float = 1e-4, enabled: bool = True
    ) -> None:
        super().__init__()
        self.size = int(size)
        self.shared = bool(shared)
        self.clip = float(clip)
        self.eps = float(eps)
        self.enabled = bool(enabled)
        width = 1 if shared else self.size
        self.register_buffer("mean", torch.zeros(width))
        self.register_buffer("var", torch.ones(width))
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        """Fold a batch (B, size) into the statistics (Chan's parallel update, in float64)."""
        if not self.enabled or x.numel() == 0:
            return
        xd = x.reshape(-1, 1 if self.shared else self.size).to(torch.float64)
        n = float(xd.shape[0])
        b_mean = xd.mean(dim=0)
        b_var = xd.var(dim=0, unbiased=False)
        c = float(self.count)
        tot = c + n
        mean = self.mean.to(torch.float64)
        delta = b_mean - mean
        new_mean = mean + delta * (n / tot)
        m2 = self.var.to(torch.float64) * c + b_var * n + delta.square() * (c * n / tot)
        self.mean.copy_(new_mean.to(torch.float32))
        self.var.copy_((m2 / tot).to(torch.float32))
        self.count.fill_(tot)

    def _std(self) -> torch.Tensor:
        return torch.sqrt(self.var + self.eps)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.enabled:
            return x
        return torch.clamp((x - self.mean) / self._std(), -self.clip, self.clip)

    def inverse(self, y: torch.Tensor) -> torch.Tensor:
        """Map normalised values back to physical units (no clipping)."""
        if not self.enabled:
            return y
        return y * self._std() + self.mean

    def scale(self) -> torch.Tensor:
        """The divisor of ``forward`` (1 when disabled), shape (1,) or (size,)."""
        if not self.enabled:
            return torch.ones_like(self.var)
        return self._std()

    def extra_repr(self) -> str:
        return f"size={self.size}, shared={self.shared}, clip={self.clip}, enabled={self.enabled}"
