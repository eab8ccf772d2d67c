"""Figures on the track: `track_heatmap` (any column aggregated per grid cell, `cell_statistic`), `episode_paths`
(chosen episodes coloured by speed, action or any column), `reward_map_figure` (a reward over the track surface)
and `crash_map` / `crash_maps` (where cars crashed, with the race's objects)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from racerlab.analysis.plots.figure import _action_table, _borders_on_top, _color_scale, _figure, _no_data
from racerlab.track import Track

STATS = ("mean", "median", "min", "max", "sum", "std", "count")


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
