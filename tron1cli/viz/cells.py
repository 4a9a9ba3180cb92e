"""How a measured figure is written in a table cell, shared by the CLI's tables (eval,
deploy-sim, deploy-robot) and the policy card's Markdown. For eval, a figure is the ``aggregate``
dict of a method's policies: ``mean`` (None when nothing was measured), ``std`` and ``n``."""

from __future__ import annotations


def figure(x: float | None, fmt: str = ".3f") -> str:
    """One figure in ``fmt`` ('0.212'), or '-' when it was not measured (None)."""
    return "-" if x is None else format(x, fmt)


def mean_std(m: dict, pct: bool) -> str:
    """'55.1 ± 0.0' (a share, in %) or '0.235 ± 0.010'; '-' when nothing was measured."""
    if m["mean"] is None:
        return "-"
    if pct:
        return f"{100.0 * m['mean']:.1f} ± {100.0 * m['std']:.1f}"
    return f"{m['mean']:.3f} ± {m['std']:.3f}"


def speed_cell(success: dict | None, progress: dict | None) -> str:
    """One commanded speed's cell, success % and command progress ('96.1 / 0.07'), with stds
    where a method has several policies; '-' for a speed not run."""
    if success is None:
        return "-"
    if success["n"] > 1 and progress is not None:
        return f"{mean_std(success, True)} / {mean_std(progress, False)}"
    prog = "-" if progress is None or progress["mean"] is None else f"{progress['mean']:.2f}"
    return f"{100.0 * success['mean']:.1f} / {prog}"
