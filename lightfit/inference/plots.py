"""Figures of a posterior run that a user looks at rather than reads."""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: Room beside the samples and the MAP on each axis of the corner plot, as a share of their span.
AXIS_PAD = 0.04


def axis_ranges(x: np.ndarray, marked) -> list[tuple[float, float]]:
    """Per column of ``x`` (n, d), an axis range that holds every sample and the ``marked`` value
    (None: none) with :data:`AXIS_PAD` of their span to spare at both ends. corner's own range is the
    samples' extremes: a MAP on the prior box's edge, where the walkers' extreme sits too, was drawn
    on the axis frame, and one beyond the walkers not at all."""
    out = []
    for j, m in enumerate(marked):
        v = x[:, j] if m is None or not np.isfinite(m) else np.append(x[:, j], m)
        lo, hi = float(np.min(v)), float(np.max(v))
        pad = AXIS_PAD * (hi - lo) or max(abs(hi), 1.0) * 1e-6  # one value: a visible width still
        out.append((lo - pad, hi + pad))
    return out


def corner_figure(samples: np.ndarray, names, x_map: dict, path: str | Path, *, title: str = "") -> Path:
    """A corner plot (corner, Foreman-Mackey 2016, JOSS 1:24) of ``samples`` (n, len(names)) with the
    MAP ``x_map`` (name → value) drawn as lines, written to ``path`` (PNG). The parameters are all
    dimensionless (leaf surface parameters and scale factors). Ridges and bananas in the 2-D panels
    are the non-identifiable combinations: the data fix where along them the walkers sit, not where
    each parameter alone does."""
    import corner
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names, x = list(names), np.asarray(samples, float).reshape(len(samples), -1)
    if len(names) == 1:  # corner indexes a grid of axes, which one parameter does not make
        fig, ax = plt.subplots(figsize=(4.5, 4))
        ax.hist(x[:, 0], bins=40, histtype="step", color="k")
        q5, q50, q95 = np.percentile(x[:, 0], (5, 50, 95))
        for q in (q5, q50, q95):
            ax.axvline(q, color="k", ls="--", lw=0.8)
        # the median and 5–95 % as corner titles each histogram of several parameters (show_titles)
        ax.set_title(f"{names[0]} = ${{{q50:.3g}}}_{{-{q50 - q5:.3g}}}^{{+{q95 - q50:.3g}}}$")
        ax.axvline(x_map.get(names[0], np.nan), color="tab:red")
        ax.set_xlabel(names[0])
        ax.set_yticks([])
    else:
        fig = corner.corner(
            x,
            labels=names,
            show_titles=True,
            title_fmt=".3g",
            quantiles=(0.05, 0.5, 0.95),
            truths=[x_map.get(n) for n in names],
            truth_color="tab:red",
            range=axis_ranges(x, [x_map.get(n) for n in names]),
        )
    fig.suptitle(
        (title + "\n" if title else "") + f"{len(samples):,} samples after burn-in; red lines: the MAP; "
        "dashed: 5, 50, 95 %; all parameters dimensionless",
        y=1.02 if len(names) > 1 else 1.08,  # above the one histogram's own title, not on it
        fontsize=10,
    )
    path = Path(path)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path
