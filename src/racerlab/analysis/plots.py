"""Analysis figures. Each function returns a matplotlib `Figure` (no pyplot, no window); `save_png` writes one.

- `training_progress(iterations)`: reward, completion (training vs in-training evaluation), lap rate,
  lap times, entropy / KL, episode length per iteration.
- `learner_health(iterations, fast_laps)`: exploration (the policy's std or entropy), the value net's explained
  variance and error, the share of training laps as fast as the best evaluation lap, the evaluation's best lap
  in 1/15 s steps (why a run stops getting faster, docs/learner.md).
- `track_heatmap(df, track, column, stat, cell)`: any column aggregated per grid cell (mean, median, min,
  max, sum, std, count or a percentile like "p90"); every step counts (`cell_statistic`), never the last
  one written.
- `episode_paths(df, track, episodes, color_by)`: paths of chosen episodes coloured by speed, action or any
  column.
- `action_usage(df)`: how often each action was taken (discrete) or a steering x speed histogram
  (continuous spaces, binned).
- `waypoint_profile(df, track)`: commanded and true speed, and steering, per waypoint.
- `lap_time_distribution(episodes)`: histogram of lap times with mean and sigma markers, and lap times by
  iteration.
- `reward_vs_lap_time(comparison)`: old and new episode rewards against lap time (reward re-scoring).
- `reward_map_figure(reward_map)`: a reward over the track surface (`racerlab.analysis.reward_tools`).
- `crash_map(df, track, layout)`: where cars crashed, with the race's boxes or bot cars' starts;
  `crash_maps(df, track, layouts)` one panel per episode layout (random layouts).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from racerlab.spec import STEP_S, STEPS_PER_SECOND
from racerlab.track import Track

STATS = ("mean", "median", "min", "max", "sum", "std", "count")
def _figure(w: float, h: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(w, h), layout="constrained")


def save_png(fig, path, dpi: int = 110) -> Path:
    """Write `fig` as a PNG to `path` (parents created); returns the path."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    return out


def _integer_x(ax) -> None:
    """Whole-number ticks (iterations), also when there is only one."""
    from matplotlib.ticker import MaxNLocator

    lo, hi = ax.get_xlim()
    if hi - lo < 2:
        mid = round(0.5 * (lo + hi))
        ax.set_xlim(mid - 1, mid + 1)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))


def _borders_on_top(ax, track: Track) -> None:
    for border in (track.inner, track.outer):
        ax.plot(*border.T, color="black", lw=1.0, zorder=2.5)


def _no_data(ax, text: str = "no data", title: str | None = None) -> None:
    """`text` in grey in the middle of an empty panel (and its `title`)."""
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="#777777")
    if title is not None:
        ax.set_title(title)


# ---------------------------------------------------------------------------------------------------------
# training progress


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


# ---------------------------------------------------------------------------------------------------------
# heatmaps on the track


def cell_statistic(x, y, values, stat: str = "mean", cell: float = 0.1, extent=None):
    """Aggregate `values` at points (x, y) over square cells of side `cell` metres.

    Returns (grid, x_edges, y_edges) with grid[row j (y), column i (x)]; cells with no point are NaN (0 for
    "count"). `extent` = (xmin, xmax, ymin, ymax) fixes the grid (points outside it are dropped); by default
    it covers the points. `stat`: one of `STATS` or "p<q>" for the q-th percentile (e.g. "p90").
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    if cell <= 0:
        raise ValueError(f"cell must be > 0, got {cell}")
    if extent is None:
        extent = (np.nanmin(x), np.nanmax(x) + 1e-9, np.nanmin(y), np.nanmax(y) + 1e-9) if x.size else (0, 1, 0, 1)
    x0, x1, y0, y1 = extent
    nx = max(int(math.ceil((x1 - x0) / cell)), 1)
    ny = max(int(math.ceil((y1 - y0) / cell)), 1)
    ix = np.floor((x - x0) / cell)
    iy = np.floor((y - y0) / cell)
    ok = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny) & np.isfinite(v if stat != "count" else x)
    flat = (iy[ok] * nx + ix[ok]).astype(np.int64)
    xe = x0 + cell * np.arange(nx + 1)
    ye = y0 + cell * np.arange(ny + 1)
    if stat == "count":
        return np.bincount(flat, minlength=nx * ny).reshape(ny, nx).astype(np.float64), xe, ye
    grid = np.full(nx * ny, np.nan)
    if flat.size:
        per = pd.Series(v[ok]).groupby(flat)
        agg = _aggregate(per, stat)
        grid[agg.index.to_numpy()] = agg.to_numpy()
    return grid.reshape(ny, nx), xe, ye


def _aggregate(per, stat: str) -> pd.Series:
    if stat in STATS:
        return per.std(ddof=0) if stat == "std" else per.agg(stat)
    if stat.startswith("p"):
        try:
            q = float(stat[1:])
        except ValueError:
            q = -1.0
        if 0 <= q <= 100:
            return per.quantile(q / 100.0)
    raise ValueError(f"unknown statistic {stat!r}; use one of {', '.join(STATS)} or a percentile like p90")


def _track_extent(track: Track, margin: float = 0.3):
    pts = np.vstack([track.inner, track.outer])
    return (pts[:, 0].min() - margin, pts[:, 0].max() + margin, pts[:, 1].min() - margin, pts[:, 1].max() + margin)


def _track_figsize(track: Track, width: float = 10.0, extra_w: float = 1.2):
    x0, x1, y0, y1 = _track_extent(track)
    aspect = (y1 - y0) / max(x1 - x0, 1e-9)
    return width + extra_w, float(np.clip(width * aspect, 3.0, 13.0)) + 0.6


def _track_ax(track: Track, title: str, extra_w: float = 1.2, waypoint_numbers: bool = False):
    from racerlab.track.plot import draw_track  # with its legend below the axes

    fig = _figure(*_track_figsize(track, extra_w=extra_w))
    ax = fig.add_subplot()
    draw_track(track, ax, waypoint_numbers=waypoint_numbers, title=title, center_line=False)
    return fig, ax


def track_heatmap(df: pd.DataFrame, track: Track, column: str = "reward", stat: str = "mean", cell: float = 0.1,
                  *, cmap: str = "viridis", min_count: int = 1, title: str | None = None, rows: str = "steps"):
    """`column` (any frame column, or a `step_kinematics` one: true_speed, slide) aggregated per `cell`-metre
    cell with `stat` over all rows of `df`; cells with fewer than `min_count` steps stay empty. `rows` says
    what a row of `df` is in the labels ("steps", or e.g. "episode ends" for one row per episode)."""
    values = _column(df, column)
    ext = _track_extent(track)
    grid, xe, ye = cell_statistic(df["x"].to_numpy(), df["y"].to_numpy(), values, stat, cell, ext)
    if min_count > 1:
        counts, _, _ = cell_statistic(df["x"].to_numpy(), df["y"].to_numpy(), values, "count", cell, ext)
        grid = np.where(counts >= min_count, grid, np.nan)
    if stat == "count":
        grid = np.where(grid > 0, grid, np.nan)
    label = f"{stat} of {column}" if stat != "count" else f"{rows} per cell"
    fig, ax = _track_ax(track, title or f"{label}, {cell * 100:.0f} cm cells, {len(df):,} {rows}")
    mesh = ax.pcolormesh(xe, ye, np.ma.masked_invalid(grid), cmap=cmap, zorder=1.5, shading="flat")
    _borders_on_top(ax, track)
    fig.colorbar(mesh, ax=ax, shrink=0.8, label=label)
    return fig


def _column(df: pd.DataFrame, column: str) -> np.ndarray:
    if column in df:
        return df[column].to_numpy(np.float64)
    from racerlab.analysis.episodes import step_kinematics

    kin = step_kinematics(df)
    if column in kin:
        return kin[column].to_numpy()
    raise KeyError(f"no column {column!r}; choose one of {', '.join([*df.columns, *kin.columns])}")


# ---------------------------------------------------------------------------------------------------------
# episode paths


def episode_paths(df: pd.DataFrame, track: Track, episodes, color_by: str = "speed", *, title: str | None = None):
    """Paths of the episodes `episodes` (unique_episode ids) coloured by `color_by`: "action" (one colour per
    discrete action), or any numeric column ("speed" = commanded, "true_speed", "reward", "steering_angle"...)."""
    from matplotlib.collections import LineCollection

    from racerlab.track.plot import track_legend

    ids = list(np.atleast_1d(np.asarray(episodes)))
    sel = df[df["unique_episode"].isin(ids)]
    if "episode_status" in sel:  # the prepare row repeats the first position with a zero action
        sel = sel[sel["episode_status"].astype(str) != "prepare"]
    fig, ax = _track_ax(track, title or f"episodes {_ids_text(ids)} coloured by {color_by}", extra_w=1.6)
    if sel.empty:
        _no_data(ax, "no such episode")
        return fig
    discrete = color_by == "action" and (sel["action"] >= 0).all()
    values = sel["action"].to_numpy(np.float64) if color_by == "action" and discrete else \
        _column(sel, "steering_angle" if color_by == "action" else color_by)
    label = "steering (°), continuous actions" if color_by == "action" and not discrete else \
        _COLOUR_LABELS.get(color_by, color_by)
    norm, cmap = _color_scale(values, discrete)
    ep = sel["unique_episode"].to_numpy()
    xy = sel[["x", "y"]].to_numpy()
    same = ep[1:] == ep[:-1]
    segs = np.stack([xy[:-1], xy[1:]], axis=1)[same]
    lc = LineCollection(segs, cmap=cmap, norm=norm, linewidths=2.2, zorder=3)
    lc.set_array(values[1:][same])
    ax.add_collection(lc)
    ax.scatter(xy[:, 0], xy[:, 1], c=values, cmap=cmap, norm=norm, s=5, zorder=3)
    ends = _mark_ends(ax, sel)
    if discrete:  # one legend right of the track: its parts, the markers, then each action's colour
        track_legend(ax, ends + _action_handles(sel, cmap, norm), center_line=False, side=True)
    else:
        fig.colorbar(lc, ax=ax, shrink=0.8, label=label)
        track_legend(ax, ends, center_line=False)
    return fig


_COLOUR_LABELS = {"speed": "commanded speed (m/s)", "true_speed": "true speed (m/s, from positions)",
                  "steering_angle": "steering (°, + = left)", "slide": "slide (°)"}


def _ids_text(ids: list) -> str:
    return ", ".join(map(str, ids[:6])) + (f" (+{len(ids) - 6})" if len(ids) > 6 else "")


def _color_scale(values: np.ndarray, discrete: bool):
    from matplotlib import colormaps
    from matplotlib.colors import BoundaryNorm, Normalize

    if discrete:
        n = int(np.nanmax(values)) + 1 if values.size else 1
        cmap = colormaps["tab20" if n > 10 else "tab10"].resampled(max(n, 2))
        return BoundaryNorm(np.arange(-0.5, max(n, 2) + 0.5), cmap.N), cmap
    # 1st-99th percentile: a standing start or one glitch must not wash out the colours of a whole lap
    lo, hi = np.nanpercentile(values, [1, 99]) if np.isfinite(values).any() else (0.0, 1.0)
    if hi - lo < 1e-6 * max(abs(lo), 1.0):
        # one value throughout (a constant commanded speed): a scale around it, so the paths take the middle
        # colour and the colour bar reads that value, not 0 on an axis labelled "1e-9+1"
        pad = max(0.1 * abs(lo), 0.1)
        lo, hi = lo - pad, hi + pad
    return Normalize(lo, hi), colormaps["plasma"]


def _mark_ends(ax, sel: pd.DataFrame) -> list:
    """Where each episode started and ended; returns the two markers for the legend."""
    g = sel.groupby("unique_episode", sort=False)
    first, last = g.head(1), g.tail(1)
    return [ax.scatter(first["x"], first["y"], marker="o", s=60, facecolor="white", edgecolor="black", zorder=4,
                       label="episode start"),
            ax.scatter(last["x"], last["y"], marker="X", s=70, color="black", zorder=4, label="episode end")]


def _action_handles(sel, cmap, norm) -> list:
    """Legend entries: the colour of each action used."""
    from matplotlib.lines import Line2D

    acts = _action_table(sel)
    return [Line2D([], [], color=cmap(norm(a)), lw=3, label=f"action {a}: {r.steering_angle:+.0f}°, {r.speed:.2f} m/s")
            for a, r in acts.iterrows()]


def _action_table(df: pd.DataFrame) -> pd.DataFrame:
    """Steering and speed of each discrete action index, as the log shows them (median per index)."""
    run = df[df["episode_status"].astype(str) != "prepare"] if "episode_status" in df else df
    return run.groupby("action")[["steering_angle", "speed"]].median()


# ---------------------------------------------------------------------------------------------------------
# actions


def action_usage(df: pd.DataFrame, *, bins: tuple[int, int] = (13, 10), title: str | None = None):
    """Discrete spaces: steps per action (bars) and a steering x speed map with disc area ∝ use. Continuous
    spaces (action -1): a 2-D histogram of steering x speed in `bins` and both marginals."""
    run = df[df["episode_status"].astype(str) != "prepare"] if "episode_status" in df else df
    fig = _figure(13, 4.8)
    axs = fig.subplots(1, 3)
    if len(run) == 0:
        for ax in axs:
            _no_data(ax)
        return fig
    if (run["action"] >= 0).all():
        _discrete_usage(axs, run)
    else:
        _continuous_usage(axs, run, bins)
    fig.suptitle(title or f"Action space usage ({len(run):,} steps)")
    return fig


def _discrete_usage(axs, run: pd.DataFrame) -> None:
    acts = _action_table(run)
    share = run["action"].value_counts(normalize=True).reindex(acts.index, fill_value=0.0)
    labels = [f"{a}\n{r.steering_angle:+.0f}°\n{r.speed:.2f}" for a, r in acts.iterrows()]
    axs[0].bar(range(len(acts)), 100 * share.to_numpy(), color="C0")
    axs[0].set_xticks(range(len(acts)), labels, fontsize=7)
    axs[0].set_ylabel("% of steps")
    axs[0].set_title("Steps per action (index, steering, speed)", fontsize=10)
    sc = axs[1].scatter(acts["steering_angle"], acts["speed"], s=3000 * share.to_numpy() + 10,
                        c=100 * share.to_numpy(), cmap="viridis", edgecolor="black", alpha=0.8)
    for a, r in acts.iterrows():
        axs[1].annotate(str(a), (r.steering_angle, r.speed), ha="center", va="center", fontsize=7)
    axs[1].set_xlabel("steering (°, + = left)")
    axs[1].set_ylabel("speed (m/s)")
    axs[1].set_title("Action map (area and colour: % of steps)", fontsize=10)
    axs[1].invert_xaxis()  # left turns on the left
    axs[1].margins(0.15)
    axs[1].figure.colorbar(sc, ax=axs[1])  # the title says what the colour is
    _usage_by_iteration(axs[2], run, acts.index.to_numpy())


def _usage_by_iteration(ax, run: pd.DataFrame, actions: np.ndarray) -> None:
    tab = pd.crosstab(run["iteration"], run["action"], normalize="index").reindex(columns=actions, fill_value=0)
    bottom = np.zeros(len(tab))
    norm, cmap = _color_scale(actions.astype(float), True)
    for a in actions:
        ax.bar(tab.index, 100 * tab[a].to_numpy(), bottom=bottom, color=cmap(norm(a)), width=1.0, label=str(a))
        bottom += 100 * tab[a].to_numpy()
    ax.set_xlabel("iteration")
    ax.set_ylabel("% of steps")
    ax.set_title("Action share per iteration", fontsize=10)
    _integer_x(ax)
    ax.legend(fontsize=6, ncol=2, title="action", title_fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))


def _continuous_usage(axs, run: pd.DataFrame, bins: tuple[int, int]) -> None:
    steer = run["steering_angle"].to_numpy()
    speed = run["speed"].to_numpy()
    h = axs[0].hist2d(steer, speed, bins=bins, cmap="viridis", cmin=1)
    axs[0].set_xlabel("steering (°, + = left)")
    axs[0].set_ylabel("speed (m/s)")
    axs[0].invert_xaxis()
    axs[0].set_title(f"Steering x speed ({bins[0]} x {bins[1]} bins)", fontsize=10)
    axs[0].figure.colorbar(h[3], ax=axs[0], label="steps")
    axs[1].hist(steer, bins=2 * bins[0], color="C0")
    axs[1].set_xlabel("steering (°)")
    axs[1].set_title("Steering", fontsize=10)
    axs[2].hist(speed, bins=2 * bins[1], color="C1")
    axs[2].set_xlabel("speed (m/s)")
    axs[2].set_title("Speed", fontsize=10)


# ---------------------------------------------------------------------------------------------------------
# per waypoint


def waypoint_of_rows(df: pd.DataFrame, track: Track | None) -> np.ndarray:
    """The waypoint each row is at: the previous waypoint along the track (by projection; the log's
    closest_waypoint when there is no track). The closing duplicate of a loop counts as waypoint 0."""
    if track is None:
        return df["closest_waypoint"].to_numpy()
    from racerlab.analysis.rescore import track_columns

    wp = track_columns(track, df["x"].to_numpy(), df["y"].to_numpy())["prev_waypoint"]
    return np.where(wp >= track.num_waypoints - 1, 0, wp) if track.closed else wp


def waypoint_profile(df: pd.DataFrame, track: Track | None = None, *, title: str | None = None):
    """Mean commanded speed, mean true speed (with its 10-90 % band) and mean steering (with its 25-75 % band)
    per waypoint, over all steps of `df` (prepare steps left out)."""
    from racerlab.analysis.episodes import step_kinematics

    run_mask = (df["episode_status"].astype(str) != "prepare").to_numpy() if "episode_status" in df else \
        np.ones(len(df), bool)
    kin = step_kinematics(df)
    wp = waypoint_of_rows(df, track)[run_mask]
    frame = pd.DataFrame({"wp": wp, "speed": df["speed"].to_numpy()[run_mask],
                          "true": kin["true_speed"].to_numpy()[run_mask],
                          "steer": df["steering_angle"].to_numpy()[run_mask]})
    g = frame.groupby("wp")
    fig = _figure(13, 6)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    if len(frame) == 0:
        _no_data(ax1)
        return fig
    idx = g.size().index.to_numpy()
    ax1.plot(idx, g["speed"].mean(), label="commanded (mean)", color="C0")
    ax1.plot(idx, g["true"].mean(), label="true, from positions (mean)", color="C1")
    ax1.fill_between(idx, g["true"].quantile(0.1), g["true"].quantile(0.9), color="C1", alpha=0.2,
                     label="true, 10-90 %")
    ax1.set_ylabel("speed (m/s)")
    ax1.legend(fontsize=8)
    ax2.plot(idx, g["steer"].mean(), color="C2", label="mean")
    ax2.fill_between(idx, g["steer"].quantile(0.25), g["steer"].quantile(0.75), color="C2", alpha=0.2,
                     label="25-75 %")
    ax2.axhline(0, color="black", lw=0.6)
    ax2.set_ylabel("steering (°, + = left)")
    ax2.set_xlabel("waypoint")
    ax2.legend(fontsize=8)
    if track is not None:
        _shade_turns(ax1, ax2, track)
    for a in (ax1, ax2):
        a.grid(alpha=0.3)
    fig.suptitle(title or f"Speed and steering per waypoint ({len(frame):,} steps)")
    return fig


def _shade_turns(ax1, ax2, track: Track) -> None:
    """Grey bands where the centre line turns tighter than 2 m radius, to read the profile against the track."""
    k = np.abs(track.curvature)
    tight = k > 0.5
    edges = np.flatnonzero(np.diff(np.concatenate([[0], tight.astype(int), [0]])))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        for ax in (ax1, ax2):
            ax.axvspan(a - 0.5, b - 0.5, color="#999999", alpha=0.12, lw=0)


# ---------------------------------------------------------------------------------------------------------
# lap times


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


# ---------------------------------------------------------------------------------------------------------
# reward map


def reward_map_figure(rm, *, cmap: str = "viridis", best_line: bool = True, title: str | None = None):
    """Draw a `reward_tools.RewardMap`: the reward as coloured quads over the road (and the margin beyond the
    borders that the map covers), with the reward-maximising line across the width when `best_line`."""
    track = rm.track
    fig, ax = _track_ax(track, title or rm.describe(), extra_w=1.6)
    r = np.ma.masked_invalid(rm.reward)
    mesh = ax.pcolormesh(rm.corner_x, rm.corner_y, r, cmap=cmap, zorder=1.5, shading="flat")
    _borders_on_top(ax, track)
    if best_line:
        bx, by = rm.best_line()
        ax.plot(bx, by, color="black", lw=1.0, ls=(0, (3, 2)), zorder=3, label="highest reward across the width")
        ax.legend(fontsize=8, loc="best", framealpha=0.9)
    fig.colorbar(mesh, ax=ax, shrink=0.8, label="reward")
    return fig


__all__ = ["STATS", "action_usage", "cell_statistic", "episode_paths", "lap_time_distribution",
           "reward_map_figure", "reward_vs_lap_time", "save_png", "track_heatmap", "training_progress",
           "waypoint_of_rows", "waypoint_profile"]


# ---------------------------------------------------------------------------------------------------------
# crashes and objects


def crash_map(df: pd.DataFrame, track: Track, layout: dict | None = None, *, note: str = "",
              title: str | None = None):
    """Every step judged `crashed` in `df` (a red cross at the model point) on the track, with the race's
    objects from `racerlab.sim.objects.race_layout` (boxes as their footprint on the track, bot cars at their
    start with an arrow along their lane); `note` is printed under the title (e.g. why no objects are drawn)."""
    hits = _crashed_rows(df)
    head = title or f"crashes: {len(hits)} in {df['unique_episode'].nunique() if 'unique_episode' in df else 1} " \
                    "episodes"
    fig, ax = _track_ax(track, head + (f"\n{note}" if note else ""))
    _draw_crashes(ax, hits, layout)
    return fig


def crash_maps(df: pd.DataFrame, track: Track, layouts: list[dict], *, most: int = 6):
    """One small crash map per layout (random layouts change at every reset): each panel draws a layout's
    objects (`layouts[k]` as `crash_map` takes it, plus "episodes": the simtrace episodes it stood for) and the
    crashes of those episodes. The `most` layouts with the most crashes are drawn, ties in episode order."""
    from racerlab.track.plot import draw_track

    hits = _crashed_rows(df)
    episode = hits["episode"] if "episode" in hits else pd.Series(0, index=hits.index)
    counts = [int(episode.isin(lay["episodes"]).sum()) for lay in layouts]
    chosen = sorted(range(len(layouts)), key=lambda k: (-counts[k], k))[:most]
    cols = min(3, len(chosen))
    rows = -(-len(chosen) // cols)
    w, h = _track_figsize(track, width=4.2 * cols, extra_w=0.0)
    fig = _figure(w, min(h / cols * rows + 0.6 * rows, 16.0))
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax, k in zip(axes, chosen, strict=False):
        eps = layouts[k]["episodes"]
        name = f"episode {eps[0]}" if len(eps) == 1 else f"episodes {eps[0]}-{eps[-1]}"
        draw_track(track, ax, waypoint_numbers=False, title=f"{name}: {counts[k]} crashes", center_line=False,
                   legend=False)
        _draw_crashes(ax, hits[episode.isin(eps)], layouts[k], labels=ax is axes[0])
    for ax in axes[len(chosen):]:
        ax.set_axis_off()
    shown = "" if len(chosen) == len(layouts) else f" (the {len(chosen)} of {len(layouts)} with the most crashes)"
    fig.suptitle(f"crashes: {len(hits)} in {len(layouts)} layouts{shown}", fontsize=11)
    return fig


def _crashed_rows(df: pd.DataFrame) -> pd.DataFrame:
    status = df["episode_status"].astype(str) if "episode_status" in df else pd.Series("", index=df.index)
    return df[status == "crashed"]


def _draw_crashes(ax, hits: pd.DataFrame, layout: dict | None, labels: bool = True) -> None:
    """The objects of `layout` (numbered) and the crashes `hits` (red crosses) on a track's axes; a legend on
    the axes when `labels`."""
    from matplotlib.patches import Polygon as Patch

    if layout is not None:
        length, width = layout["size"]
        colour = "#e08a1e" if layout["kind"] == "box" else "#2a6fd6"
        corners = np.array([[0.5, 0.5], [0.5, -0.5], [-0.5, -0.5], [-0.5, 0.5]]) * [length, width]
        for k, ((x, y), yaw) in enumerate(zip(layout["xy"], layout["yaw"], strict=True)):
            c, s_ = math.cos(yaw), math.sin(yaw)
            pts = np.c_[x + corners[:, 0] * c - corners[:, 1] * s_, y + corners[:, 0] * s_ + corners[:, 1] * c]
            ax.add_patch(Patch(pts, closed=True, facecolor=colour, edgecolor="black", lw=0.8, zorder=3,
                               label=("box" if layout["kind"] == "box" else "bot car at the start") if k == 0
                               else None))
            ax.annotate(str(k), (x, y), xytext=(6, 6), textcoords="offset points", fontsize=8, zorder=5)
            if layout["kind"] == "bot":
                ax.arrow(x, y, 0.35 * c, 0.35 * s_, width=0.02, color=colour, zorder=4)
    if len(hits):
        ax.scatter(hits["x"], hits["y"], marker="X", s=60, color="#d62728", edgecolor="black", linewidths=0.5,
                   zorder=6, label=f"crash ({len(hits)})")
    else:
        _no_data(ax, "no crashes")
    if labels and (len(hits) or layout is not None):
        ax.legend(loc="upper right", fontsize=8)
