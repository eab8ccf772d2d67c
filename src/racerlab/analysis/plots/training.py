"""The training's figures, per iteration: `training_progress` (reward, completion, lap rate, lap times,
entropy / KL, episode length) and `learner_health` (exploration, the value net, fast training laps, the
evaluation's best lap in steps; docs/learner.md)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from racerlab.analysis.plots.figure import _figure, _integer_x, _no_data
from racerlab.spec import STEPS_PER_SECOND


def training_progress(it: pd.DataFrame, title: str = "Training progress"):
    """Six panels per iteration from `episodes.iteration_summary`; columns it lacks are left out."""
    fig = _figure(13, 7)
    axs = fig.subplots(2, 3)
    x = it.index.to_numpy()
    ax = axs[0, 0]
    ax.plot(x, it["reward_mean"], marker=".", label="mean")
    ax.fill_between(x, it["reward_mean"] - it["reward_std"], it["reward_mean"] + it["reward_std"], alpha=0.2,
                    label="± std")
    ax.set_title("Episode reward")
    ax.legend(fontsize=8)
    ax = axs[0, 1]
    ax.plot(x, it["progress_mean"], marker=".", label="training episodes (simtrace)")
    _maybe(ax, it, "train_completion", "training (TrainingMetrics)", ls="--")
    _maybe(ax, it, "eval_completion", "in-training evaluation", marker="s")
    ax.set_ylim(0, 105)
    ax.set_title("Mean completion %")
    ax.legend(fontsize=8)
    ax = axs[0, 2]
    ax.plot(x, 100 * it["completion_rate"], marker=".", label="training")
    if "eval_lap_rate" in it:
        ax.plot(x, 100 * it["eval_lap_rate"], marker="s", label="evaluation")
    ax.set_ylim(-3, 103)
    ax.set_title("Complete laps %")
    ax.legend(fontsize=8)
    ax = axs[1, 0]
    _lap_time_panel(ax, it)
    ax = axs[1, 1]
    _entropy_panel(ax, it)
    ax = axs[1, 2]
    ax.plot(x, it["time_mean"], marker=".")
    ax.set_title("Mean episode time (s)")
    lo, hi = (float(x.min()), float(x.max())) if x.size else (0.0, 1.0)
    pad = max(0.5, 0.03 * (hi - lo))
    return _by_iteration(fig, axs, title, (lo - pad, hi + pad))  # the same iterations on every panel


def _by_iteration(fig, axs, title: str, xlim=None):
    """Every panel of `axs` over iterations (whole numbers, `xlim` on each, also one without data), and the title."""
    for a in axs.flat:
        a.set_xlabel("iteration", fontsize=8)
        a.tick_params(labelsize=8)
        a.grid(alpha=0.3)
        if xlim is not None:
            a.set_xlim(*xlim)
        _integer_x(a)
    fig.suptitle(title)
    return fig


def _has(it, col: str) -> bool:
    """Whether the iterations table has column `col` with at least one value."""
    return col in it and bool(it[col].notna().any())


def _maybe(ax, it, col, label, **kw):
    if _has(it, col):
        ax.plot(it.index, it[col], label=label, **kw)


def _twin(ax, it, lines, *, ylabel: str = "", log: bool = False, legend: bool = True):
    """A second y axis on `ax` with `lines` ((column, label, plot keywords), ...) of the iterations table."""
    ax2 = ax.twinx()
    for col, label, kw in lines:
        ax2.plot(it.index, it[col], label=label, **kw)
    if log:
        ax2.set_yscale("log")
    ax2.tick_params(labelsize=8)
    if ylabel:
        ax2.set_ylabel(ylabel, fontsize=8)
    if legend:
        ax2.legend(fontsize=8, loc="upper right")


def _lap_time_panel(ax, it):
    if it["lap_time_min"].notna().any():
        x = it.index.to_numpy()
        ax.plot(x, it["lap_time_min"], marker=".", label="best")
        ax.plot(x, it["lap_time_p25"], ls="--", label="25th percentile")
        ax.plot(x, it["lap_time_mean"], ls=":", label="mean")
        _maybe(ax, it, "eval_lap_time_min", "best in evaluation", marker="s")
        ax.legend(fontsize=8)
    else:
        _no_data(ax, "no complete lap yet")
    ax.set_title("Lap time (s)")


def _entropy_panel(ax, it):
    if not _has(it, "entropy"):
        _no_data(ax, "no metrics.jsonl (entropy) in this log", "Policy entropy")
        return
    ax.plot(it.index, it["entropy"], marker=".", color="C4", label="entropy")
    ax.set_title("Policy entropy (and approx. KL)")
    if _has(it, "approx_kl"):
        _twin(ax, it, [("approx_kl", "approx. KL", {"color": "C5", "ls": "--"})], ylabel="approx. KL", legend=False)


def learner_health(it: pd.DataFrame, fast_laps: pd.Series | None = None, title: str = "The learner"):
    """Why a run stops getting faster, per iteration (docs/learner.md): the exploring actions' spread, how well
    the value net predicts the returns, how often the training laps are as fast as the best evaluation lap
    (`fast_laps`, a share per iteration), and the evaluation's best lap on its 1/15 s steps."""
    fig = _figure(13, 7)
    axs = fig.subplots(2, 2)
    _spread_panel(axs[0, 0], it)
    _value_panel(axs[0, 1], it)
    ax = axs[1, 0]
    if fast_laps is not None and fast_laps.notna().any():
        ax.plot(fast_laps.index, 100 * fast_laps, marker=".", color="C2")
    else:
        _no_data(ax, "no complete lap yet")
    ax.set_title("Training laps within 1/15 s of the best evaluation lap (%)")
    _eval_steps_panel(axs[1, 1], it)
    return _by_iteration(fig, axs, title)


def _spread_panel(ax, it):
    shown = [c for c in ("action_std_steer", "action_std_speed") if _has(it, c)]
    for c in shown:
        ax.plot(it.index, it[c], marker=".", label=c.removeprefix("action_std_"))
    if shown:
        ax.set_title("Exploration: the policy's std ([-1, 1] action units), learning rate")
        ax.legend(fontsize=8, loc="upper left")
        if _has(it, "learning_rate"):
            _twin(ax, it, [("learning_rate", "learning rate", {"color": "k", "ls": "--", "lw": 1})], log=True)
    elif _has(it, "entropy"):
        ax.plot(it.index, it["entropy"], marker=".", color="C4")
        ax.set_title("Exploration: policy entropy")
    else:
        _no_data(ax, "no metrics.jsonl in this log", "Exploration")


def _value_panel(ax, it):
    if not _has(it, "explained_variance"):
        _no_data(ax, "no metrics.jsonl in this log")
    else:
        ax.plot(it.index, it["explained_variance"], marker=".", color="C0", label="explained variance")
        ax.set_ylim(-0.5, 1.05)
        ax.legend(fontsize=8, loc="upper left")
        if _has(it, "value_rmse"):
            _twin(ax, it, [("value_rmse", "value error (RMS, reward units)", {"color": "C3", "ls": "--"}),
                           ("advantage_std", "advantage std", {"color": "C1", "ls": ":"})])
    ax.set_title("The value net: returns it explains, its error")


def _eval_steps_panel(ax, it):
    if not _has(it, "eval_best_lap"):
        _no_data(ax, "no evaluation lap yet")
    else:
        steps = np.round(it["eval_best_lap"] * STEPS_PER_SECOND)
        ax.plot(it.index, steps, marker=".", ls="none", color="C4", label="best evaluation lap")
        ax.plot(it.index, steps.cummin(), color="k", lw=1, label="best so far")
        ax.legend(fontsize=8)
    ax.set_title("Evaluation: best lap in 1/15 s steps")
