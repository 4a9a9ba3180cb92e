"""Vision-CTS PPO with one critic per reward group (torch only: no MuJoCo, nothing from the env).

Public API: :class:`ObsDims`, :class:`LearnerConfig`, :class:`VisionCTSLearner`, :class:`StudentPolicy`.
The names load on first use (PEP 562), so ``tron1cli.learn.config`` (plain dataclasses) is read
without importing torch: the CLI checks its options before torch's 2-3 s import.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

#: public name -> the submodule that defines it
_HOME = {
    "LearnerConfig": "config",
    "ObsDims": "config",
    "StudentPolicy": "models",
    "VisionCTS": "models",
    "RunningNormalizer": "normalizer",
    "tune_glibc_malloc": "perf",
    "VisionCTSLearner": "ppo",
    "RolloutStorage": "storage",
    "compute_gae": "storage",
    "normalize_advantages": "storage",
}

__all__ = sorted(_HOME)


def __getattr__(name: str) -> Any:
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(f"{__name__}.{_HOME[name]}"), name)
    globals()[name] = value
    return value
