"""PNG plots: training curves against wall-clock minutes or env steps."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from tron1cli.viz.campaign import X_AXES, campaign_phases, read_metrics  # noqa: E402


def first_reached(
    rows: list[dict], survival: float = 0.9, error: float = 0.3, group: str = "student"
) -> dict:
    """Wall-clock minutes at which the survival and tracking-error thresholds were first met."""
    out: dict[str, float | None] = {"survival_min": None, "tracking_min": None, "both_min": None}
    for m in rows:
        s, e, t = m.get(f"{group}/survival"), m.get(f"{group}/vel_tracking_error"), m["wall_s"] / 60.0
        ok_s = s is not None and s >= survival
        ok_e = e is not None and e <= error
        if ok_s and out["survival_min"] is None:
            out["survival_min"] = t
        if ok_e and out["tracking_min"] is None:
            out["tracking_min"] = t
        if ok_s and ok_e and out["both_min"] is None:
            out["both_min"] = t
    return out


def x_axis(x: str) -> tuple[str, str, float]:
    """(label, metrics key, divisor) of x axis ``x``; ValueError names the valid ones."""
    try:
        return X_AXES[x]
    except KeyError:
        raise ValueError(f"x must be one of {', '.join(X_AXES)}, got {x!r}") from None


def training_curves(
    runs: dict[str, Path],
    out_png: Path,
    group: str = "student",
    mark: float | None = None,
    x: str = "minutes",
) -> Path:
    """Survival and velocity tracking error of ``group`` against wall-clock minutes (``x="minutes"``)
    or millions of env steps (``x="env_steps"``: runs on machines of other speeds compare), one line
    per run (``mark``: a vertical line at that x, e.g. at a time budget)."""
    xlabel, key, scale = x_axis(x)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    for label, run_dir in runs.items():
        rows = read_metrics(run_dir)
        t = [m[key] / scale for m in rows]
        ax1.plot(t, [m.get(f"{group}/survival") for m in rows], label=label)
        ax2.plot(t, [m.get(f"{group}/vel_tracking_error") for m in rows], label=label)
    ax1.axhline(0.9, color="grey", ls="--", lw=0.8)
    ax2.axhline(0.3, color="grey", ls="--", lw=0.8)
    ax1.set(xlabel=xlabel, ylabel=f"{group} survival (share of episodes)", ylim=(0, 1.02))
    ax2.set(xlabel=xlabel, ylabel=f"{group} velocity tracking error (m/s)", ylim=(0, None))
    for ax in (ax1, ax2):
        if mark is not None:
            ax.axvline(mark, color="k", ls=":", lw=0.8)
        ax.grid(alpha=0.3)
        ax.legend()
    return _save(fig, out_png)


def campaign_curves(run_dirs: Path | list[Path], out_png: Path, smooth: int = 20, x: str = "minutes") -> Path:
    """A perceptive campaign against wall-clock minutes or millions of env steps (``x``, as in
    :func:`training_curves`; resumed runs included; a list of run directories is its phases in
    order, each start marked by a dotted line): survival and velocity tracking error of both
    groups, terrain level per type, and the student's heightmap reconstruction error; each curve a
    running mean over ``smooth`` iterations within a phase."""
    xlabel, x_key, scale = x_axis(x)
    dirs = [Path(run_dirs)] if isinstance(run_dirs, (str, Path)) else [Path(d) for d in run_dirs]
    rows = campaign_phases(dirs)
    t = [m[x_key] / scale for m in rows]

    def series(key: str) -> list[float]:
        out, window, phase = [], [], None
        for m in rows:
            if m["phase"] != phase:
                window, phase = [], m["phase"]
            v = m.get(key)
            window = (window + ([v] if v is not None else []))[-smooth:]
            out.append(sum(window) / len(window) if window else float("nan"))
        return out

    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    (a_s, a_e), (a_l, a_r) = axes
    for g in ("teacher", "student"):
        a_s.plot(t, series(f"{g}/survival"), label=g)
        a_e.plot(t, series(f"{g}/vel_tracking_error"), label=g)
    for key in sorted(k for k in rows[-1] if k.startswith("terrain/level/")):
        a_l.plot(t, series(key), label=key.rsplit("/", 1)[1])
    a_r.plot(t, series("learn/heightmap_err_cm"), color="C3")
    a_s.set(ylabel="survival (share of episodes)", ylim=(0, 1.02))
    a_e.set(ylabel="velocity tracking error (m/s)", ylim=(0, None))
    a_l.set(ylabel="terrain level (0 .. 9 hardest)", ylim=(0, 9.2))
    a_r.set(ylabel="student heightmap error (cm, RMS)", ylim=(0, None))
    starts = [m[x_key] / scale for a, m in zip(rows, rows[1:], strict=False) if m["phase"] != a["phase"]]
    for ax in axes.flat:
        for start in starts:
            ax.axvline(start, color="k", ls=":", lw=0.8)
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3)
    for ax in (a_s, a_e, a_l):
        ax.legend(fontsize=8)
    names = (
        " -> ".join(d.name for d in dirs)
        if len(dirs) <= 3
        else f"{len(dirs)} phases, {dirs[0].name} -> {dirs[-1].name}"
    )
    fig.suptitle(f"{names}: {rows[-1]['env_steps'] / 1e6:.1f} M env steps")
    return _save(fig, out_png)


def _save(fig, out_png: Path) -> Path:
    from tron1cli.fileio import atomic_write

    out_png = Path(out_png)
    fig.tight_layout()
    try:  # whole or not at all: a full disk keeps the earlier figure
        atomic_write(
            out_png, lambda f: fig.savefig(f, dpi=110, format=out_png.suffix[1:] or "png"), fsync=False
        )
    finally:
        plt.close(fig)
    return out_png


def success_by_speed(
    curves: dict[str, dict[float, dict]],
    out_png: Path,
    title: str = "",
    xlabel: str = "commanded forward speed (m/s)",
) -> Path:
    """Fig. 5 style: success rate (%) against commanded speed along one velocity dimension,
    mean +/- std band per label.

    curves: label -> speed (m/s, or rad/s for yaw rate) -> {"mean": 0-1, "std": 0-1}.
    """
    fig, ax = plt.subplots(figsize=(6, 4))
    for label, by_speed in curves.items():
        v = sorted(by_speed)
        m = [100 * by_speed[s]["mean"] for s in v]
        sd = [100 * (by_speed[s]["std"] or 0.0) for s in v]
        ax.plot(v, m, marker="o", label=label)
        ax.fill_between(
            v,
            [a - b for a, b in zip(m, sd, strict=True)],
            [a + b for a, b in zip(m, sd, strict=True)],
            alpha=0.2,
        )
    ax.set(xlabel=xlabel, ylabel="success rate (%)", ylim=(0, 102), title=title)
    ax.grid(alpha=0.3)
    ax.legend()
    return _save(fig, out_png)


def push_survival(survival: dict[str, dict[str, float]], out_png: Path, title: str = "") -> Path:
    """Fig. 6 style: survival rate (%) per push type, one bar group per label.

    survival: label -> push type -> 0-1.
    """
    labels = list(survival)
    types = list(next(iter(survival.values())))
    width = 0.8 / max(len(labels), 1)
    fig, ax = plt.subplots(figsize=(max(6, 0.6 * len(types) * max(len(labels), 1)), 4))
    for k, label in enumerate(labels):
        xs = [i + (k - (len(labels) - 1) / 2) * width for i in range(len(types))]
        ax.bar(xs, [100 * survival[label][t] for t in types], width=width, label=label)
    ax.set_xticks(range(len(types)), types)
    ax.set(xlabel="push", ylabel="survival (%)", ylim=(0, 105), title=title)
    ax.grid(alpha=0.3, axis="y")
    ax.legend()
    return _save(fig, out_png)
