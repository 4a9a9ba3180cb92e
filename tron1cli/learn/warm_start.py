"""Start a model from another run's weights wherever the shapes agree (``tron1 train --init``).

The networks take their inputs as concatenations with the newer parts last (actor ``[o_t, l^e,
l^h]``, critic ``[e_t, h_t]`` and ``[l^e, l^h]``), so a blind run's weights fit a perceptive
model's first layers once the extra input columns are added at zero: the warm-started model then
computes exactly what the source did, whatever the new inputs hold, and learns to use them from
there. Tensors of the same name and shape are copied; a 2-D weight with the same rows and more
columns gets the source's columns and zeros after them; everything else keeps its fresh
initialisation (new modules, such as the heightmap encoder and the depth estimator of a
perceptive run, and any tensor whose shape disagrees otherwise).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import torch
from torch import nn


@dataclass
class WarmStart:
    """What :func:`warm_start` did, by parameter or buffer name."""

    copied: list[str] = field(default_factory=list)
    widened: list[str] = field(default_factory=list)  # source columns copied, new columns zero
    fresh: list[str] = field(default_factory=list)  # kept their initialisation

    def summary(self) -> str:
        return f"{len(self.copied)} tensors copied, {len(self.widened)} widened, {len(self.fresh)} fresh"

    def to_dict(self) -> dict[str, list[str]]:
        return {"copied": self.copied, "widened": self.widened, "fresh": self.fresh}


def warm_start(model: nn.Module, source: Mapping[str, torch.Tensor]) -> WarmStart:
    """Copy ``source`` (a ``state_dict`` of the same architecture family) into ``model`` in place."""
    report = WarmStart()
    target = model.state_dict()
    with torch.no_grad():
        for name, dst in target.items():
            src = source.get(name)
            if src is None or not torch.is_tensor(src) or src.dtype != dst.dtype:
                report.fresh.append(name)
            elif src.shape == dst.shape:
                dst.copy_(src)
                report.copied.append(name)
            elif (
                src.ndim == 2
                and dst.ndim == 2
                and src.shape[0] == dst.shape[0]
                and src.shape[1] < dst.shape[1]
            ):
                dst.zero_()
                dst[:, : src.shape[1]] = src
                report.widened.append(name)
            else:
                report.fresh.append(name)
    model.load_state_dict(target)
    return report


def _wider_inputs(src: torch.Tensor, dst: torch.Tensor) -> bool:
    """A linear layer's weight (out, in) with the same outputs and more inputs."""
    return src.ndim == dst.ndim == 2 and src.shape[0] == dst.shape[0] and src.shape[1] < dst.shape[1]
