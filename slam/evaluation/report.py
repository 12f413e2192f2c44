"""Tables in the layout of the VB paper (Tables 4-5: one block per noise setting, rows Path,
Path-X, Path-Y, Feature; one column per algorithm), extended with the VR paper's line-feature
errors (rho, theta), Neff before and after resampling / variance reduction, distinct particles,
run time, real-time factor and accuracy (eq. 50); rows without a value in any column are left
out. And a PNG of trajectories and Neff over time."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from auvgw.slam.evaluation.metrics import RunResult, Summary, summarise
from auvgw.slam.landmark.registry import DISPLAY_NAMES

__all__ = ["format_table", "plot_results", "summaries_by_algorithm"]

ROWS: list[tuple[str, str, str]] = [
    ("Path", "path", "{:.4f}"),
    ("Path-X", "path_x", "{:.4f}"),
    ("Path-Y", "path_y", "{:.4f}"),
    ("Feature", "feature", "{:.4f}"),
    ("Feature rho (m)", "feature_rho", "{:.4f}"),
    ("Feature theta (deg)", "feature_theta_deg", "{:.4f}"),
    ("Mean Neff", "neff", "{:.1f}"),
    ("Neff after", "neff_post", "{:.1f}"),
    ("Distinct particles", "distinct", "{:.1f}"),
    ("Run time (s)", "runtime_s", "{:.2f}"),
    ("Real-time factor", "realtime_factor", "{:.0f}x"),
    ("Accuracy (%)", "accuracy_pct", "{:.3f}"),
    ("Diverged runs", "diverged", "{:d}"),
]


def summaries_by_algorithm(results: list[RunResult], algorithms: Sequence[str]) -> list[Summary]:
    """One :class:`Summary` per algorithm, in the given order."""
    return [summarise([r for r in results if r.algorithm == a]) for a in algorithms]


def _cell(fmt: str, value: float) -> str:
    return (
        "-"
        if value is None or (isinstance(value, float) and math.isnan(value))
        else fmt.format(value)
    )


def format_table(title: str, summaries: Sequence[Summary], markdown: bool = False) -> str:
    """The comparison table of one noise setting, as aligned text or a Markdown table."""
    names = [DISPLAY_NAMES.get(s.algorithm, s.algorithm) for s in summaries]
    rows = [
        [label] + [_cell(fmt, getattr(s, attr)) for s in summaries] for label, attr, fmt in ROWS
    ]
    rows = [r for r in rows if any(c not in ("-", "0") for c in r[1:])]
    if markdown:
        out = [f"**{title}**", "", "| | " + " | ".join(names) + " |"]
        out.append("|---" * (len(names) + 1) + "|")
        out += ["| " + " | ".join(r) + " |" for r in rows]
        return "\n".join(out) + "\n"
    widths = [max(len(r[0]) for r in rows)] + [
        max(len(names[i]), *(len(r[i + 1]) for r in rows)) for i in range(len(names))
    ]
    line = "  ".join(
        [" " * widths[0]] + [n.rjust(w) for n, w in zip(names, widths[1:], strict=True)]
    )
    out = [title, line]
    out += [
        "  ".join(
            [r[0].ljust(widths[0])] + [c.rjust(w) for c, w in zip(r[1:], widths[1:], strict=True)]
        )
        for r in rows
    ]
    return "\n".join(out) + "\n"


def plot_results(
    results: list[RunResult], algorithms: Sequence[str], path: Path, title: str
) -> None:
    """PNG: the first run's true and estimated trajectories with the true features (points or
    wall segments), and the mean Neff over the runs per scan for the particle filters, before
    (solid) and after (dotted) resampling / variance reduction."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(14, 6))
    first = min(r.run for r in results)
    shown = [r for r in results if r.run == first]
    if shown:
        r0 = shown[0]
        if r0.segments is not None:
            for i, (x1, y1, x2, y2) in enumerate(r0.segments):
                ax1.plot([y1, y2], [x1, x2], color="0.4", lw=3, label="walls" if i == 0 else None)
        else:
            ax1.plot(r0.landmarks[:, 1], r0.landmarks[:, 0], "k+", ms=5, label="features (truth)")
        ax1.plot(r0.truth[:, 1], r0.truth[:, 0], "k-", lw=2, label="truth")
    for r in shown:
        ax1.plot(r.est[:, 1], r.est[:, 0], lw=1, label=DISPLAY_NAMES.get(r.algorithm, r.algorithm))
    ax1.set_xlabel("y east (m)")
    ax1.set_ylabel("x north (m)")
    ax1.set_aspect("equal", adjustable="datalim")
    ax1.set_title(f"trajectories, run {first}")
    ax1.legend(fontsize=8)
    for a in algorithms:
        mine = [r for r in results if r.algorithm == a and not r.diverged]
        if not mine or not np.any(np.isfinite(mine[0].neff)):
            continue
        n = min(len(r.neff) for r in mine)
        mean = np.mean([r.neff[:n] for r in mine], axis=0)
        t = mine[0].t[:n] if mine[0].t is not None else np.arange(n)
        (line,) = ax2.plot(t, mean, lw=0.8, label=DISPLAY_NAMES.get(a, a) + " (before)")
        posts = [r.neff_post[:n] for r in mine if r.neff_post is not None]
        if posts:
            ax2.plot(
                t,
                np.mean(posts, axis=0),
                ":",
                color=line.get_color(),
                lw=0.8,
                label=DISPLAY_NAMES.get(a, a) + " (after)",
            )
    ax2.set_xlabel("vehicle time (s)" if shown and shown[0].t is not None else "scan")
    ax2.set_ylabel("Neff (mean over runs)")
    ax2.set_title("Neff before / after resampling or variance reduction")
    if ax2.get_lines():
        ax2.legend(fontsize=8)
    else:
        ax2.text(0.5, 0.5, "no particle filter", ha="center", va="center", transform=ax2.transAxes)
    fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
