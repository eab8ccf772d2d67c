"""What `racerlab line` writes for a racer: a picture, the line as .npy/.csv, a paste-ready Python
list for a reward function, and a discrete action space (`model_metadata.json`) fitted to the line.

The action space. Each point of the line needs a steering angle (its curvature through the
car's bicycle model) and has a target speed; weighted by the time the car spends there, those
(steering, speed) pairs are grouped into clusters (k-means on steering/30° and speed/4 m/s) and
each cluster's centre is an action. No action asks for more than the grip allows at its angle,
and two recovery actions (full lock each way, at a speed the grip holds there) are added so a
policy that strays can still turn back.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from racerlab.line.core import RacingLine
from racerlab.model import DiscreteActions, ModelMetadata
from racerlab.spec import MAX_STEERING_DEG
from racerlab.track import Track

DEFAULT_ACTIONS = 15  # including the two recovery actions
CSV_COLUMNS = ("s_m", "x_m", "y_m", "speed_mps", "time_s", "curvature_1pm", "heading_deg", "steering_deg")


def grip_speed(steering_deg, line: RacingLine) -> np.ndarray:
    """Fastest speed the car's grip allows at a steady steering angle, m/s (capped at its top speed).

    The simulator's bicycle with the car's yaw gain g(v): κ = cos β · g(v) · tan δ / L; v²·κ grows with v, so a
    bisection finds where it reaches the grip."""
    car = line.car
    wheels = np.abs(np.asarray(steering_deg, dtype=np.float64)) + abs(car.steer_offset_deg)  # the side it turns more
    tan_d = np.tan(np.radians(wheels))

    def lateral(v):
        t = car.yaw_gain_at(v) * tan_d
        return v * v * car.saturated(t / np.sqrt(1.0 + 0.25 * t * t) / car.wheelbase_m, v)

    top = car.top_speed()
    lo, hi = np.zeros_like(tan_d), np.full_like(tan_d, top)
    for _ in range(48):
        mid = 0.5 * (lo + hi)
        ok = lateral(mid) <= car.grip_mps2
        lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
    return np.where(lateral(np.full_like(tan_d, top)) <= car.grip_mps2, top, lo)


def action_space(line: RacingLine, n_actions: int = DEFAULT_ACTIONS, seed: int = 0) -> DiscreteActions:
    """A discrete action space of `n_actions` (≥ 3) actions fitted to what the line asks of the car."""
    if n_actions < 3:
        raise ValueError(f"an action space from a line needs at least 3 actions, got {n_actions}")
    steer = np.clip(line.steering_deg, -MAX_STEERING_DEG, MAX_STEERING_DEG)
    dt = np.diff(np.append(line.time, line.flying_lap_time))
    feats = np.stack([steer / MAX_STEERING_DEG, line.speed / line.car.top_speed()], axis=1)
    centres = _kmeans(feats, dt, n_actions - 2, seed)
    s_act = np.round(centres[:, 0] * MAX_STEERING_DEG, 1)
    v_act = _floor_cm(np.minimum(centres[:, 1] * line.car.top_speed(), grip_speed(s_act, line)))
    v_lock = float(_floor_cm(min(float(line.speed.min()), float(grip_speed(MAX_STEERING_DEG, line)))))
    pairs = {(float(s), float(v)) for s, v in zip(s_act, v_act, strict=True)}
    pairs |= {(-MAX_STEERING_DEG, v_lock), (MAX_STEERING_DEG, v_lock)}
    ordered = sorted(pairs)
    return DiscreteActions(tuple(p[0] for p in ordered), tuple(p[1] for p in ordered))


def _floor_cm(v):
    """Speeds rounded down to 0.01 m/s (down, so that no rounding pushes one past the grip)."""
    return np.floor(np.asarray(v) * 100.0 + 1e-9) / 100.0


def _kmeans(x: np.ndarray, w: np.ndarray, k: int, seed: int, iters: int = 100) -> np.ndarray:
    """Weighted k-means (Lloyd) with k-means++ seeding from a fixed seed; returns (k', 2) centres, k' ≤ k."""
    rng = np.random.default_rng(seed)
    k = min(k, len(np.unique(x, axis=0)))
    centres = [x[rng.choice(len(x), p=w / w.sum())]]
    for _ in range(1, k):
        d2 = np.min(((x[:, None, :] - np.array(centres)[None]) ** 2).sum(-1), axis=1) * w
        centres.append(x[rng.choice(len(x), p=d2 / d2.sum())] if d2.sum() > 0 else x[0])
    c = np.array(centres)
    for _ in range(iters):
        label = np.argmin(((x[:, None, :] - c[None]) ** 2).sum(-1), axis=1)
        mass = np.bincount(label, weights=w, minlength=len(c))
        new = np.stack([np.bincount(label, weights=w * x[:, j], minlength=len(c)) for j in range(2)], axis=1)
        new = np.where(mass[:, None] > 0, new / np.maximum(mass, 1e-12)[:, None], c)
        if np.allclose(new, c):
            break
        c = new
    return c


def model_metadata(line: RacingLine, n_actions: int = DEFAULT_ACTIONS, version: float = 5.0) -> dict:
    """An AWS `model_metadata.json` dict of `version` (the car the line was solved for): the fitted discrete actions,
    front camera, shallow CNN, PPO."""
    meta = ModelMetadata(action_space(line, n_actions), ("FRONT_FACING_CAMERA",),
                         "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", "clipped_ppo", float(version))
    return meta.to_json()


def csv_text(line: RacingLine) -> str:
    cols = np.column_stack([line.s, line.xy, line.speed, line.time, line.curvature, line.heading_deg,
                            line.steering_deg])
    rows = [",".join(f"{v:.5f}" for v in row) for row in cols]
    return "\n".join([",".join(CSV_COLUMNS), *rows]) + "\n"


def python_text(line: RacingLine) -> str:
    """A Python file a racer pastes into (or next to) a reward function: `racing_line = [[x, y, speed], ...]`."""
    body = ",\n".join(f"    [{x:.4f}, {y:.4f}, {v:.3f}]" for (x, y), v in zip(line.xy, line.speed, strict=True))
    return (f'"""Racing line for {line.track_name} by racerlab: {line.method}, margin {line.margin_m} m, '
            f"{len(line.xy)} points, {line.length:.2f} m.\n\n"
            f"Each row is [x, y, speed]: the base point of the car (m) and the speed it can have there (m/s)\n"
            f"under racerlab's car limits, in driving order from the start line. Theoretical best lap "
            f"{line.lap_time:.3f} s\n(standing start), {line.flying_lap_time:.3f} s flying.\n"
            f'"""\n\nLAP_TIME = {line.lap_time:.3f}\nFLYING_LAP_TIME = {line.flying_lap_time:.3f}\n\n'
            f"racing_line = [\n{body},\n]\n")


def draw_line(line: RacingLine, track: Track, ax=None):
    """The line on the track, coloured by speed, with a colour bar; returns the axes."""
    from matplotlib.collections import LineCollection
    from matplotlib.lines import Line2D

    from racerlab.track.plot import draw_track, track_legend

    ax = draw_track(track, ax=ax, waypoint_numbers=False, center_line=False, title=False, legend=False)
    pts = np.vstack([line.xy, line.xy[:1]])
    segs = np.stack([pts[:-1], pts[1:]], axis=1)
    lc = LineCollection(segs, cmap="plasma", linewidths=2.5, zorder=6)
    lc.set_array(line.speed)
    lc.set_clim(float(line.speed.min()), line.car.max_speed_mps)
    ax.add_collection(lc)
    ax.figure.colorbar(lc, ax=ax, shrink=0.7, label="speed (m/s)")
    track_legend(ax, [Line2D([], [], color=lc.cmap(0.6), lw=2.5, label="racing line, coloured by speed")],
                 center_line=False)
    ax.set_title(f"{line.track_name}: {line.method} line, margin {line.margin_m} m — lap {line.lap_time:.3f} s "
                 f"(flying {line.flying_lap_time:.3f} s), {line.length:.2f} m", fontsize=10)
    return ax


def save_png(line: RacingLine, track: Track, path, dpi: int = 150) -> Path:
    from matplotlib.figure import Figure

    span = np.ptp(np.vstack([track.inner, track.outer]), axis=0) + 1.0
    fig = Figure(figsize=(11.5, float(np.clip(10.0 * span[1] / span[0], 3.0, 14.0)) + 0.6))
    draw_line(line, track, fig.add_subplot())
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    return Path(path)


def write_all(line: RacingLine, track: Track, out_dir, n_actions: int = DEFAULT_ACTIONS,
              version: float = 5.0) -> dict[str, Path]:
    """Write every file into `out_dir` (created), model_metadata.json of `version`; returns {kind: path}."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = f"{_safe(line.track_name)}_{line.method}"
    paths = {"png": out / f"{stem}.png", "npy": out / f"{stem}.npy", "csv": out / f"{stem}.csv",
             "py": out / f"{stem}.py", "model_metadata": out / "model_metadata.json"}
    save_png(line, track, paths["png"])
    np.save(paths["npy"], line.xy)
    paths["csv"].write_text(csv_text(line))
    paths["py"].write_text(python_text(line))
    paths["model_metadata"].write_text(json.dumps(model_metadata(line, n_actions, version), indent=2) + "\n")
    return paths


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name) or "track"


