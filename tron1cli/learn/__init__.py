"""Vision-CTS PPO with one critic per reward group (torch only: no MuJoCo, nothing from the env).

Public API: :class:`ObsDims`, :class:`LearnerConfig`, :class:`VisionCTSLearner`, :class:`StudentPolicy`.
"""

from tron1cli.learn.config import LearnerConfig, ObsDims
from tron1cli.learn.models import StudentPolicy, VisionCTS
from tron1cli.learn.normalizer import RunningNormalizer
from tron1cli.learn.perf import tune_glibc_malloc
from tron1cli.learn.ppo import VisionCTSLearner
from tron1cli.learn.storage import RolloutStorage, compute_gae, normalize_advantages

__all__ = [
    "LearnerConfig",
    "ObsDims",
    "RolloutStorage",
    "RunningNormalizer",
    "StudentPolicy",
    "VisionCTS",
    "VisionCTSLearner",
    "compute_gae",
    "normalize_advantages",
    "tune_glibc_malloc",
]
