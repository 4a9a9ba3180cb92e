"""The figures over several deploy-sim runs of one policy (``tron1 deploy-sim --runs N``)."""

from __future__ import annotations

import statistics
from pathlib import Path

from tron1cli.evaluation.binomial import wilson_interval
from tron1cli.viz.cells import figure


def runs_summary(reps: list[dict]) -> dict:
    """Survival over the runs (share and 95 % Wilson interval), every fall (seed, time, cause), and
    the worst or typical pipeline figures: depth rate range (Hz), dropped frames, worst frame-age
    and inference p99 (ms), slowest and median real-time factor; means of per-run means for
    tracking (m/s) and heightmap error (cm). ``reps``: reports of :meth:`DeploySim.run`, in seed
    order."""
    if not reps:
        raise ValueError("no runs to summarise")
    n = len(reps)
    survived = sum(r["survived"] for r in reps)
    lo, hi = wilson_interval(survived, n)

    def pick(key: str, fn):  # fn over the runs that have the figure; None where none has it
        vals = [r[key] for r in reps if r.get(key) is not None]
        return fn(vals) if vals else None

    return {
        "policy": reps[0]["policy"],
        "terrain": reps[0]["terrain"],
        "terrain_types": sorted({r["terrain_type"] for r in reps}),
        "level": reps[0]["level"],
        "requested_duration_s": reps[0]["requested_duration_s"],
        "runs": n,
        "seeds": [reps[0]["seed"], reps[-1]["seed"]],
        "survived": survived,
        "survival": survived / n,
        "survival_ci95": [lo, hi],
        "falls": [
            {"seed": r["seed"], "t_s": r["duration_s"], "ended": r["ended"], "fell_by": r["fell_by"]}
            for r in reps
            if not r["survived"]
        ],
        "simulated_s": sum(r["duration_s"] for r in reps),
        "vel_tracking_error_mean": pick("vel_tracking_error", statistics.fmean),
        "reconstruction_error_cm_mean": pick("reconstruction_error_cm", statistics.fmean),
        "depth_rate_hz_min": pick("depth_rate_hz", min),
        "depth_rate_hz_max": pick("depth_rate_hz", max),
        "depth_dropped": pick("depth_dropped", sum),
        "depth_age_ms_p99_max": pick("depth_age_ms_p99", max),
        "policy_ms_p99_max": pick("policy_ms_p99", max),
        "realtime_factor_min": pick("realtime_factor", min),
        "realtime_factor_median": pick("realtime_factor", statistics.median),
    }


def summary_rows(sm: dict) -> list[tuple[str, str]]:
    """(figure, value) rows of a :func:`runs_summary`, as deploy-sim's table and the card show them."""
    lo, hi = sm["survival_ci95"]
    falls = "; ".join(
        f"seed {f['seed']} at {f['t_s']:.2f} s ({f['fell_by'] or f['ended']})" for f in sm["falls"]
    )
    rows = [
        (
            "survived (95 % Wilson interval)",
            f"{sm['survived']} of {sm['runs']} ({sm['survival']:.0%}; {lo:.0%}-{hi:.0%})",
        ),
        ("falls (seed, time, cause)", falls or "none"),
        ("velocity tracking error, mean (m/s)", figure(sm["vel_tracking_error_mean"], ".3f")),
        ("heightmap reconstruction error, mean (cm)", figure(sm["reconstruction_error_cm_mean"], ".2f")),
        ("policy inference p99, worst run (ms)", figure(sm["policy_ms_p99_max"], ".3f")),
        (
            "real-time factor, slowest / median run",
            f"{figure(sm['realtime_factor_min'], '.2f')} / {figure(sm['realtime_factor_median'], '.2f')}",
        ),
    ]
    if sm["depth_rate_hz_min"] is not None:
        rows += [
            (
                "depth rate, lowest / highest run (Hz)",
                f"{sm['depth_rate_hz_min']:.1f} / {sm['depth_rate_hz_max']:.1f}",
            ),
            ("depth frames dropped, all runs", str(sm["depth_dropped"])),
            ("depth frame age p99, worst run (ms of sim time)", figure(sm["depth_age_ms_p99_max"], ".1f")),
        ]
    return rows


def summary_title(sm: dict) -> str:
    """One line naming the policy, terrain, level, runs and seeds of a :func:`runs_summary`."""
    return (
        f"{Path(sm['policy']).name}, {', '.join(sm['terrain_types'])} level {sm['level']}, {sm['runs']} "
        f"runs of {sm['requested_duration_s']:g} s (seeds {sm['seeds'][0]}-{sm['seeds'][1]})"
    )
