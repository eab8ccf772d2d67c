"""Lap times and rewards: `lap_time_distribution` (a histogram with mean and sigma, lap times by iteration) and
`reward_vs_lap_time` (logged and re-scored episode rewards against lap time and progress)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from racerlab.analysis.plots.figure import _figure, _integer_x, _no_data
from racerlab.spec import STEP_S


def lap_time_distribution(episodes: pd.DataFrame, *, title: str | None = None):
    """Histogram of the lap times of complete laps (mean and ±1σ, ±2σ marked) and lap time by iteration."""
    laps = episodes[episodes["complete"]]
    fig = _figure(13, 4.5)
    ax1, ax2 = fig.subplots(1, 2)
    if laps.empty:
        _no_data(ax1, "no complete lap")
        _no_data(ax2, "no complete lap")
        fig.suptitle(title or "Lap times")
        return fig
    t = laps["lap_time"].to_numpy()
    ax1.hist(t, bins=_step_bins(t), color="C0", alpha=0.8)
    mu, sd = float(t.mean()), float(t.std())
    ax1.axvline(mu, color="black", label=f"mean {mu:.2f} s")
    for k, ls in ((1, "--"), (2, ":")):
        for sign in (-1, 1):
            ax1.axvline(mu + sign * k * sd, color="black", ls=ls, lw=0.8,
                        label=f"±{k}σ ({sd * k:.2f} s)" if sign > 0 else None)
    ax1.axvline(t.min(), color="C3", label=f"best {t.min():.2f} s")
    ax1.set_xlabel("lap time (s)")
    ax1.set_ylabel("laps")
    ax1.legend(fontsize=8)
    ax2.scatter(laps["iteration"], t, s=10, alpha=0.6)
    best = laps.groupby("iteration")["lap_time"].min()
    ax2.plot(best.index, best.to_numpy(), color="C3", marker="o", ms=4, label="best per iteration")
    ax2.set_xlabel("iteration")
    _integer_x(ax2)
    ax2.set_ylabel("lap time (s)")
    ax2.legend(fontsize=8)
    for a in (ax1, ax2):
        a.grid(alpha=0.3)
    fig.suptitle(title or f"Lap times ({len(laps)} complete laps of {len(episodes)} episodes)")
    return fig


# ---------------------------------------------------------------------------------------------------------
# reward re-scoring


def reward_vs_lap_time(cmp: pd.DataFrame, *, title: str | None = None):
    """From `rescore.compare`: logged and new episode reward against lap time (complete laps), and against
    progress (all episodes); Spearman rank correlations in the titles."""
    from racerlab.analysis.rescore import _spearman

    fig = _figure(14, 4.6)
    axs = fig.subplots(1, 3)
    laps = cmp[cmp["complete"]]
    for ax, col, name in ((axs[0], "reward", "logged reward"), (axs[1], "new_reward", "new reward")):
        if laps.empty:
            _no_data(ax, "no complete lap")
        else:
            ax.scatter(laps["lap_time"], laps[col], s=12, alpha=0.7, color="C0" if col == "reward" else "C1")
        rho = _spearman(laps[col], laps["lap_time"]) if len(laps) else math.nan
        ax.set_title(f"{name} vs lap time (ρ = {rho:.2f})", fontsize=10)
        ax.set_xlabel("lap time (s)")
        ax.set_ylabel(f"{name} per episode")
    ax = axs[2]
    ax.scatter(cmp["progress"], cmp["reward"] / _scale(cmp["reward"]), s=8, alpha=0.5, label="logged (scaled)")
    ax.scatter(cmp["progress"], cmp["new_reward"] / _scale(cmp["new_reward"]), s=8, alpha=0.5, label="new (scaled)")
    ax.set_xlabel("progress %")
    ax.set_ylabel("episode reward / max")
    ax.set_title(f"rewards vs progress (ρ logged {_spearman(cmp['reward'], cmp['progress']):.2f}, "
                 f"new {_spearman(cmp['new_reward'], cmp['progress']):.2f})", fontsize=10)
    ax.legend(fontsize=8)
    for a in axs:
        a.grid(alpha=0.3)
    fig.suptitle(title or "Reward re-scoring: a good reward ranks faster laps higher (negative ρ with lap time)")
    return fig


def _step_bins(t: np.ndarray, step: float = STEP_S, most: int = 40) -> np.ndarray:
    """Histogram edges a whole number of simulator steps wide (lap times are multiples of 1/15 s), at most
    `most` bins, so that no bin is empty only because of where its edges fall."""
    n = int(math.ceil((t.max() - t.min()) / step)) + 1
    width = step * max(1, int(math.ceil(n / most)))
    return np.arange(t.min() - step / 2, t.max() + width, width)


def _scale(s: pd.Series) -> float:
    m = float(np.nanmax(np.abs(s.to_numpy()))) if s.notna().any() else 1.0
    return m if m > 0 else 1.0
