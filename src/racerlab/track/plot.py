"""Track pictures: `draw_track` puts a track on matplotlib axes so other plots can draw over it.

    >>> ax = draw_track(track)                       # road, borders, centre line, start, direction
    >>> ax.plot(xs, ys)                              # a trajectory on top, in the same metres
    >>> save_track_png(track, "track.png")

matplotlib is imported inside the functions (Agg, no window) so that importing racerlab stays fast.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from racerlab.track.core import Track, ring_area

ROAD_COLOR = "#cfd2d6"
GRASS_COLOR = "#eef3e8"
BORDER_COLOR = "#2b2b2b"
CENTER_COLOR = "#e0a100"
START_COLOR = "#d62728"
LABEL_COLOR = "#555555"
MAX_LABELS = 40  # waypoint numbers shown at most, so that they stay readable


def _road_path(track: Track):
    """The road as one matplotlib Path: the outer ring with the inner ring as a hole."""
    from matplotlib.path import Path as MplPath

    if track.closed:
        # the hole must wind the other way round for the non-zero fill rule
        same_way = (ring_area(track.outer) > 0) == (ring_area(track.inner) > 0)
        rings = [track.outer, track.inner[::-1] if same_way else track.inner]
    else:
        rings = [np.vstack([track.outer, track.inner[::-1], track.outer[:1]])]
    verts, codes = [], []
    for ring in rings:
        verts.append(ring)
        codes += [MplPath.MOVETO] + [MplPath.LINETO] * (len(ring) - 2) + [MplPath.CLOSEPOLY]
    return MplPath(np.vstack(verts), codes)


def label_step(num_waypoints: int, max_labels: int = MAX_LABELS) -> int:
    """Every how many waypoints a number is written: 1, 2, 5, 10, 20, 50, ... so at most `max_labels`."""
    for mag in range(7):
        for base in (1, 2, 5):
            step = base * 10**mag
            if num_waypoints / step <= max_labels:
                return step
    return max(num_waypoints, 1)


def _normals(track: Track) -> np.ndarray:
    """Unit vectors at each waypoint pointing from the centre line towards the outer border."""
    d = track.outer - track.center
    n = np.hypot(*d.T)[:, None]
    return np.divide(d, n, out=np.zeros_like(d), where=n > 0)


def _draw_start(ax, track: Track) -> None:
    ax.plot(*np.stack([track.inner[0], track.outer[0]]).T, color=START_COLOR, lw=3, solid_capstyle="butt",
            zorder=4, label="start")


def _draw_arrow(ax, track: Track) -> None:
    """An arrow on the centre line a little after the start, pointing the driving direction."""
    s0 = min(0.06 * track.length, 1.2)
    a, b = track.point_at(s0), track.point_at(s0 + min(0.5, 0.03 * track.length))
    ax.annotate("", xy=b, xytext=a, zorder=5,
                arrowprops={"arrowstyle": "-|>", "color": START_COLOR, "lw": 2, "mutation_scale": 18})


def _draw_numbers(ax, track: Track, step: int) -> None:
    n = track.num_waypoints - (1 if track.closed else 0)
    out = _normals(track)
    offset = 0.18
    for i in range(0, n, step):
        x, y = track.outer[i] + out[i] * offset
        ax.plot(*track.center[i], marker="o", ms=2, color=LABEL_COLOR, zorder=3)
        ax.text(x, y, str(i), fontsize=6, color=LABEL_COLOR, ha="center", va="center", zorder=3)


def draw_track(track: Track, ax=None, waypoint_numbers: bool = True, *, label_every: int | None = None,
               title: str | bool = True, center_line: bool = True, road_color: str = ROAD_COLOR,
               background: str | None = GRASS_COLOR, legend: bool = True):
    """Draw `track` on `ax` (a new figure when None) in metres with equal aspect; returns the axes.

    Draws the road surface, both borders, the dashed centre line, the start line and an arrow for
    the driving direction, and (optionally) every `label_every`-th waypoint number (chosen so that
    at most `MAX_LABELS` are written when None), with a legend below the axes saying what each is
    (`track_legend` redraws it with more entries, e.g. a plot's start and end markers).
    """
    from matplotlib.patches import PathPatch

    if ax is None:
        from matplotlib.figure import Figure

        ax = Figure(figsize=_figsize(track)).add_subplot()
    if background:
        ax.set_facecolor(background)
    ax.add_patch(PathPatch(_road_path(track), facecolor=road_color, edgecolor="none", zorder=1))
    for border in (track.inner, track.outer):
        ax.plot(*border.T, color=BORDER_COLOR, lw=1.2, zorder=2)
    if center_line:
        ax.plot(*track.center.T, color=CENTER_COLOR, lw=1, ls=(0, (4, 4)), zorder=2)
    _draw_start(ax, track)
    _draw_arrow(ax, track)
    if waypoint_numbers:
        _draw_numbers(ax, track, label_every or label_step(track.num_waypoints))
    if title:
        ax.set_title(title if isinstance(title, str) else _title(track), fontsize=10)
    if legend:
        track_legend(ax, center_line=center_line, waypoint_numbers=waypoint_numbers, road_color=road_color)
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel("x (m)", fontsize=8)
    ax.set_ylabel("y (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    return ax


def track_legend(ax, extra=(), *, center_line: bool = True, waypoint_numbers: bool = False,
                 road_color: str = ROAD_COLOR, side: bool = False):
    """A legend below `ax` (right of it with `side`) naming the track's parts, then the `extra` handles
    (artists with labels)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = [Patch(facecolor=road_color, edgecolor=BORDER_COLOR, label="road, between the borders"),
               Line2D([], [], color=START_COLOR, lw=3, label="start / finish line"),
               Line2D([], [], color=START_COLOR, marker=">", ls="-", lw=1.5, label="driving direction")]
    if center_line:
        handles.append(Line2D([], [], color=CENTER_COLOR, lw=1, ls=(0, (4, 4)), label="centre line"))
    if waypoint_numbers:
        handles.append(Line2D([], [], color=LABEL_COLOR, marker="o", ms=3, ls="", label="waypoint (number)"))
    handles += list(extra)
    if side:
        return ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, frameon=False)
    return ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.06), ncol=min(len(handles), 4),
                     fontsize=8, frameon=False)


def _title(track: Track) -> str:
    way = "counter-clockwise" if track.is_ccw else "clockwise"
    return f"{track.name}: {track.length:.2f} m, {track.width:.2f} m wide, {way}"


def _figsize(track: Track) -> tuple[float, float]:
    span = np.ptp(np.vstack([track.inner, track.outer]), axis=0) + 1.0
    aspect = float(span[1] / span[0]) if span[0] > 0 else 1.0
    width = 10.0
    return width, float(np.clip(width * aspect, 3.0, 14.0)) + 0.6


def save_track_png(track: Track, path, dpi: int = 150, **kwargs) -> Path:
    """Write a picture of `track` (as `draw_track` draws it, `kwargs` passed on) to `path`; returns the path."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=_figsize(track))
    draw_track(track, fig.add_subplot(), **kwargs)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    return out
