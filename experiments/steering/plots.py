"""Figures of ``seal eval steering`` (matplotlib, Agg): risk and plausibility against alpha (structured solid,
random dashed, one colour per vector) and the speed calibration curves (relative speed change against tau)."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def write_plots(report: dict[str, Any], out: Path) -> list[Path]:
    """Write ``risk_vs_alpha.png``, ``plausibility_vs_alpha.png`` and ``speed_calibration.png``; their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    fig2, ax2 = plt.subplots(figsize=(6, 4))
    for i, (name, sec) in enumerate(report["risk"].items()):
        colour = f"C{i % 10}"
        ax = axes[0 if sec["feature"] == "activity" else 1]
        ax.plot(sec["alphas"], sec["structured"][sec["feature"]], "-o", color=colour, label=name)
        ax.plot(sec["alphas"], sec["random"][sec["feature"]], "--", color=colour)
        ax2.plot(sec["alphas"], sec["structured"]["plausible"], "-o", color=colour, label=name)
        ax2.plot(sec["alphas"], sec["random"]["plausible"], "--", color=colour)
        if sec.get("project_road"):  # the decoder's own candidates, before the road projection
            ax2.plot(sec["alphas"], sec["structured"]["plausible_raw"], ":", color=colour, lw=1)
    for ax, title in zip(axes, ("activity risk (paper 000)", "proximity risk to the ego"), strict=True):
        ax.set(xlabel="alpha (latent std)", ylabel="prior-weighted risk", title=title)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    ax2.axhline(0.94, color="grey", lw=0.8)
    ax2.set(xlabel="alpha (latent std)", ylabel="share of drivable candidates",
            title="plausibility (dashed: random, dotted: before projection)")
    ax2.legend(fontsize=7)
    for f, name in ((fig, "risk_vs_alpha.png"), (fig2, "plausibility_vs_alpha.png")):
        f.tight_layout()
        f.savefig(out / name, dpi=110)
        plt.close(f)
        paths.append(out / name)
    fig, ax = plt.subplots(figsize=(6, 5))
    for name, sec in report["speed"].items():
        ax.plot(sec["taus_pct"], [100 * c for c in sec["change"]], "-o", ms=3, label=name)
    ax.plot([-50, 50], [-50, 50], color="grey", lw=0.8)
    ax.axhspan(-50, 50, color="grey", alpha=0.08)
    ax.set(xlabel="tau (%, 100 = one class gap)", ylabel="relative speed change (%)", title="speed control vectors")
    ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(out / "speed_calibration.png", dpi=110)
    plt.close(fig)
    paths.append(out / "speed_calibration.png")
    return paths
