"""What every figure of `analysis.plots` shares: a new figure (no pyplot, no window), `save_png`, whole-number
iteration ticks, the track's borders, an empty panel's note, the colours of a column's values and the logged
steering and speed of each discrete action."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from racerlab.track import Track


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


def _action_table(df: pd.DataFrame) -> pd.DataFrame:
    """Steering and speed of each discrete action index, as the log shows them (median per index)."""
    run = df[df["episode_status"].astype(str) != "prepare"] if "episode_status" in df else df
    return run.groupby("action")[["steering_angle", "speed"]].median()
