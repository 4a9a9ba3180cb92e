"""The paper's published figures that our evaluations are held against (one source for cards,
docs and tables).

Table I ("Ours", the student on the real method): at the hardest training level, 1024 envs x
500 steps (10 s), three training seeds; each figure is (mean, std over the seeds). The paper's
orientation error is labelled m/s^2 there; ours is |g_b - (0, 0, -1)| of the unit gravity
direction, so only its order of magnitude compares. The paper reports neither command progress
nor traverse rate.
"""

from __future__ import annotations

#: Table I, row "Ours": terrain -> ``tron1 eval`` metric -> (mean, std over 3 seeds);
#: success_rate as a share (0-1), the others in the units of :mod:`tron1cli.evaluation.protocol`
PAPER_TABLE_I: dict[str, dict[str, tuple[float, float]]] = {
    "stairs": {
        "success_rate": (0.8030, 0.0443),
        "orientation_error": (0.06, 0.01),
        "angular_velocity_error": (0.64, 0.05),
        "velocity_tracking_error": (0.26, 0.01),
        "reconstruction_error_cm": (2.57, 0.14),
    },
    "slopes": {
        "success_rate": (0.752, 0.0624),
        "orientation_error": (0.06, 0.01),
        "angular_velocity_error": (0.73, 0.11),
        "velocity_tracking_error": (0.31, 0.04),
        "reconstruction_error_cm": (6.58, 3.81),
    },
    "discrete": {
        "success_rate": (0.8281, 0.031),
        "orientation_error": (0.05, 0.01),
        "angular_velocity_error": (0.64, 0.04),
        "velocity_tracking_error": (0.24, 0.01),
        "reconstruction_error_cm": (3.25, 0.07),
    },
    "rough": {
        "success_rate": (0.8503, 0.0129),
        "orientation_error": (0.05, 0.01),
        "angular_velocity_error": (0.64, 0.01),
        "velocity_tracking_error": (0.26, 0.01),
        "reconstruction_error_cm": (2.33, 0.08),
    },
}
