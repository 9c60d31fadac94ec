"""The convergence figure: each constraint's loss against the iteration, per expression, levels marked.

Read from the registration logs (``{results}/{subject}/{method}/{expression}.json``) that ``gpja register``
writes; nothing is re-optimised.
"""
from __future__ import annotations

import numpy as np

from gpja.errors import InputError
from gpja.methods import label
from gpja.report.drawing import set_title
from gpja.report.figures import FigureRequest

CONSTRAINT_LABELS = {"color": r"$\mathcal{L}_{color}$", "depth": r"$\mathcal{L}_{depth}$",
                     "normal": r"$\mathcal{L}_{normal}$"}


def loss_curves(log: dict) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], list[int]]:
    """``({constraint: (iteration, loss)}, level start iterations)`` of a GPJA registration log.

    One constraint is back-propagated per iteration, in rotation, so each constraint's losses are spread
    evenly over its level's iterations. Iterations and losses are (k,) float64 arrays.
    """
    curves: dict[str, list] = {}
    starts, start = [], 0
    for level in log.get("levels") or []:
        if "iterations" not in level:  # a flow stage (gpja.register.flow) matches images, it has no descent
            continue
        starts.append(start)
        n = int(level["iterations"])
        for name, values in (level.get("losses") or {}).items():
            values = np.asarray(values, dtype=np.float64)
            if len(values):
                x = start + (np.arange(len(values)) + 0.5) * n / len(values)
                curves.setdefault(name, []).append((x, values))
        start += n
    return {k: (np.concatenate([x for x, _ in v]), np.concatenate([y for _, y in v])) for k, v in curves.items()}, starts


def draw_convergence(request: FigureRequest):
    """One panel per constraint: loss against iteration for every expression; dashed lines where a stage ends
    (the warm-up, when the log has one, then each refinement)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files, subject, method = request.files, request.subject, request.method
    logs = {e: files.registration_log(subject, method, e) for e in request.expressions}
    curves = {e: loss_curves(log) for e, log in logs.items()}
    names = [n for n in ("color", "depth", "normal") if any(n in c for c, _ in curves.values())]
    if not names:
        raise InputError(files.layout.method_dir(subject, method), "the registration logs hold no losses")
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.2), squeeze=False)
    for ax, name in zip(axes[0], names):
        for expression, (c, starts) in curves.items():
            if name in c:
                ax.plot(*c[name], lw=1.0, label=expression)
        for s in next(iter(curves.values()))[1][1:]:
            ax.axvline(s, color="grey", ls="--", lw=0.8)
        ax.set_yscale("log")
        ax.set_xlabel("iteration (dashed: end of warm-up or level)")
        ax.set_title(CONSTRAINT_LABELS.get(name, name), fontsize=10)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("L1 loss (per pixel)")
    axes[0][-1].legend(fontsize=7)
    set_title(fig, f"Convergence of {label(method)}, subject {subject}", fontsize=10)
    fig.tight_layout()
    return fig
