"""Run configuration: dataclasses with units in their docstrings, validated, never mutated."""

from tron1cli.config.env import (
    CommandConfig,
    EnvConfig,
    GaitConfig,
    InitConfig,
    NoiseConfig,
    TerminationConfig,
)

__all__ = ["CommandConfig", "EnvConfig", "GaitConfig", "InitConfig", "NoiseConfig", "TerminationConfig"]
