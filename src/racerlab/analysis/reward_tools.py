"""Reward functions without logs: `check_reward` calls one over states sampled over a whole track and reports
what went wrong and how the reward behaves; `reward_map` evaluates it over the track surface.

States are built like the simulator builds params (`rescore.params_columns`: the same projection, widths,
closest waypoints, left/right and wheel test), so what the check reports is what training would meet.

Sampled states (`check_reward`), stratified per centre segment so every part of the track is visited:
position anywhere across the width and up to 40 % of it beyond either border (off-track and
some-wheels-off cases), heading near the track direction and sometimes any direction, speed 0.1-4 m/s,
steering ±30°, progress from a random start line, steps consistent with progress at 0.5-3.5 m/s, some
states driving the track reversed, and some on the finish line with progress 100 (lap complete).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from racerlab.analysis.rescore import RewardProblem, params_columns, score, wrap_degrees
from racerlab.reward import as_reward_function
from racerlab.spec import MAX_SPEED, MAX_STEERING_DEG, MIN_SPEED, STEP_S
from racerlab.track import Track

OFF_ROAD_MARGIN = 0.4  # sampled positions reach this fraction of the width beyond each border
BAND_COUNT = 8


def _cross_points(track: Track, s: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Points at arc length `s` and fraction `u` across the road (0 = left border, 1 = right border, in the
    driving direction; values outside [0, 1] lie beyond the borders). Border rows are interpolated along the
    centre segment, so the points follow the track's own cross-sections."""
    ws = track.waypoint_s
    seg = np.clip(np.searchsorted(ws, s, side="right") - 1, 0, len(ws) - 2)
    t = ((s - ws[seg]) / np.maximum(track.segment_lengths[seg], 1e-12))[:, None]
    left = track.left[seg] * (1 - t) + track.left[seg + 1] * t
    right = track.right[seg] * (1 - t) + track.right[seg + 1] * t
    return left + np.asarray(u)[:, None] * (right - left)


def _steps_for(progress, length, avg_speed):
    """A plausible step count for having driven `progress` % of the lap at `avg_speed` (first call sees 2)."""
    return np.maximum(2.0, 1.0 + np.ceil(progress / 100.0 * length / (avg_speed * STEP_S)))


# ---------------------------------------------------------------------------------------------------------
# sampling


@dataclass
class States:
    """Sampled states: the params columns, and what they were drawn with (for the statistics)."""

    params: object  # rescore.ParamsColumns
    frame: pd.DataFrame  # per state: distance ratio, heading error, speed, steering, offtrack, ...


def sample_states(track: Track, per_segment: int = 100, seed: int = 0, *, reverse_share: float = 0.1,
                  lap_complete_share: float = 0.03) -> States:
    rng = np.random.default_rng(seed)
    nseg = track.num_waypoints - 1
    n = nseg * per_segment
    rev = rng.random(n) < reverse_share
    seg = np.repeat(np.arange(nseg), per_segment)
    s = np.empty(n)
    pts = np.empty((n, 2))
    head = np.empty(n)
    lap = rng.random(n) < lap_complete_share
    u = _lateral_fractions(rng, n)
    for flag, t in ((False, track), (True, track.reverse())):
        sel = rev == flag
        ws = t.waypoint_s
        si = ws[seg[sel]] + rng.random(sel.sum()) * t.segment_lengths[seg[sel]]
        # lap-complete states sit just before the finish line
        si = np.where(lap[sel], t.length - rng.uniform(0.0, 0.1, sel.sum()), si)
        s[sel] = si
        pts[sel] = _cross_points(t, si, u[sel])
        head[sel] = np.degrees(t.heading_at(si))
    offset = np.where(rng.random(n) < 0.1, rng.uniform(-180, 180, n), rng.normal(0, 25, n))
    heading = wrap_degrees(head + offset)
    speed = rng.uniform(MIN_SPEED, MAX_SPEED, n)
    steer = rng.uniform(-MAX_STEERING_DEG, MAX_STEERING_DEG, n)
    start = rng.uniform(0, track.length, n)
    progress = np.where(lap, 100.0, np.mod(s - start, track.length) / track.length * 100.0)
    steps = _steps_for(progress, track.length, rng.uniform(0.5, 3.5, n))
    pc = params_columns(track, pts[:, 0], pts[:, 1], heading, speed, steer, progress, steps, reversed=rev,
                        sim_time=steps * STEP_S)
    c = pc.cols
    frame = pd.DataFrame({
        "distance_ratio": c["distance_from_center"] / np.maximum(0.5 * c["track_width"], 1e-9),
        "heading_error": np.abs(wrap_degrees(heading - head)), "speed": speed, "steering_angle": steer,
        "all_wheels_on_track": c["all_wheels_on_track"], "is_offtrack": c["is_offtrack"],
        "lap_complete": lap, "is_reversed": rev})
    return States(pc, frame)


def _lateral_fractions(rng, n: int) -> np.ndarray:
    """Mostly on the road, 15 % beyond a border (up to OFF_ROAD_MARGIN of the width)."""
    u = rng.random(n)
    off = rng.random(n) < 0.15
    beyond = rng.uniform(0, OFF_ROAD_MARGIN, n)
    side = rng.random(n) < 0.5
    return np.where(off, np.where(side, -beyond, 1.0 + beyond), u)


# ---------------------------------------------------------------------------------------------------------
# the check


SWEEPS = {
    "distance from centre (fraction of half width, + = left)": ("lateral", [-1.2, -1.0, -0.75, -0.5, -0.25, 0.0,
                                                                             0.25, 0.5, 0.75, 1.0, 1.2]),
    "heading error (°, + = pointing left of the track)": ("heading", [-90, -45, -20, -10, 0, 10, 20, 45, 90]),
    "speed (m/s)": ("speed", [0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0]),
    "steering (°)": ("steering", [-30, -15, 0, 15, 30]),
}
BASELINE = {"lateral": 0.0, "heading": 0.0, "speed": 2.0, "steering": 0.0}


@dataclass
class CheckReport:
    track: Track
    states: int
    rewards: np.ndarray
    frame: pd.DataFrame
    problems: list[RewardProblem] = field(default_factory=list)
    failed: int = 0
    sweeps: dict[str, pd.DataFrame] = field(default_factory=dict)
    sweep_failed: int = 0  # failures among the sweep states (their problems are merged into `problems`)

    @property
    def ok(self) -> bool:
        return self.failed == 0 and self.sweep_failed == 0

    def bands(self, count: int = BAND_COUNT) -> pd.DataFrame:
        """Share of states whose reward falls in each of `count` equal-width bands from min to max."""
        r = self.rewards[np.isfinite(self.rewards)]
        if r.size == 0:
            return pd.DataFrame(columns=["from", "to", "share"])
        lo, hi = float(r.min()), float(r.max())
        edges = np.linspace(lo, hi if hi > lo else lo + 1e-9, count + 1)
        counts, _ = np.histogram(r, edges)
        return pd.DataFrame({"from": edges[:-1], "to": edges[1:], "share": counts / r.size})

    def format(self) -> str:
        """The report as text for the terminal."""
        return "\n".join(_format_report(self))


def check_reward(reward, track: Track, *, per_segment: int = 100, seed: int = 0) -> CheckReport:
    """Call `reward` (a callable or a reward_function.py path) on states over the whole of `track`.

    Never raises for the reward's own failures: exceptions (with the params that caused them), values that
    are not numbers, not finite or beyond ±1e5 are collected in `problems`.
    """
    fn = as_reward_function(reward)
    st = sample_states(track, per_segment, seed)
    res = score(fn, st.params)
    for p in res.problems:
        p.label = "sampled state"
    report = CheckReport(track, len(st.params), res.rewards, st.frame, res.problems, res.failed)
    report.sweeps, sweep_problems, report.sweep_failed = _sweeps(fn, track)
    known = {p.message: p for p in report.problems}
    for p in sweep_problems:
        if p.message in known:
            known[p.message].count += p.count
        else:
            p.label = "sweep state"
            known[p.message] = p
            report.problems.append(p)
    return report


def _sweeps(fn, track: Track):
    """Vary one factor at a time from a baseline state (on the centre line, heading along the track, 2 m/s,
    straight) at the middle of every centre segment; mean, min and max over the segments."""
    nseg = track.num_waypoints - 1
    s_mid = track.waypoint_s[:-1] + 0.5 * track.segment_lengths
    out, problems, failed = {}, [], 0
    for name, (factor, values) in SWEEPS.items():
        vals = np.repeat(np.asarray(values, dtype=np.float64), nseg)
        s = np.tile(s_mid, len(values))
        cfg = {k: np.full(vals.size, v) for k, v in BASELINE.items()}
        cfg[factor] = vals
        u = 0.5 - 0.5 * cfg["lateral"]  # +1 = the left border
        pts = _cross_points(track, s, u)
        heading = wrap_degrees(np.degrees(track.heading_at(s)) + cfg["heading"])
        progress = s / track.length * 100.0
        pc = params_columns(track, pts[:, 0], pts[:, 1], heading, cfg["speed"], cfg["steering"], progress,
                            _steps_for(progress, track.length, cfg["speed"]))
        res = score(fn, pc)
        problems += res.problems
        failed += res.failed
        g = pd.Series(res.rewards).groupby(vals)
        out[name] = pd.DataFrame({"mean": g.mean(), "min": g.min(), "max": g.max()})
    return out, problems, failed


def _format_report(rep: CheckReport) -> list[str]:
    r = rep.rewards
    fin = r[np.isfinite(r)]
    lines = [f"reward check on {rep.track.name} ({rep.track.length:.2f} m): {rep.states:,} sampled states"]
    if rep.ok:
        lines.append("  no exceptions; every value a finite number within ±1e5")
    else:
        lines.append(f"  PROBLEMS: {rep.failed:,} of {rep.states:,} sampled states failed"
                     + (f", {rep.sweep_failed:,} sweep states" if rep.sweep_failed else ""))
        for p in rep.problems:
            lines.append("  - " + p.describe().replace("\n", "\n    "))
    if fin.size == 0:
        return lines
    on = rep.frame["all_wheels_on_track"].to_numpy() & np.isfinite(r)
    off = rep.frame["is_offtrack"].to_numpy() & np.isfinite(r)
    lines.append(f"  reward: min {fin.min():.4g}, mean {fin.mean():.4g}, max {fin.max():.4g}; "
                 f"all wheels on: mean {_mean(r[on])}; off track: mean {_mean(r[off])}; "
                 f"lap complete: mean {_mean(r[rep.frame['lap_complete'].to_numpy() & np.isfinite(r)])}")
    if fin.min() == fin.max():
        lines.append(f"  every state gets the same reward {fin.min():.4g}: the reward teaches nothing")
        return lines
    lines.append("  share of states per reward band:")
    for _, b in rep.bands().iterrows():
        bar = "#" * int(round(40 * b["share"]))
        lines.append(f"    {b['from']:>10.4g} .. {b['to']:<10.4g} {100 * b['share']:5.1f} % {bar}")
    for name, sweep in rep.sweeps.items():
        lines.append(f"  reward vs {name} (others: centre line, along the track, 2 m/s, straight; "
                     "mean [min, max] over the track):")
        for v, row in sweep.iterrows():
            lines.append(f"    {v:>6g}: {row['mean']:.4g} [{row['min']:.4g}, {row['max']:.4g}]")
    return lines


def _mean(a: np.ndarray) -> str:
    return f"{a.mean():.4g}" if a.size else "n/a"


# ---------------------------------------------------------------------------------------------------------
# the reward over the track surface


@dataclass
class RewardMap:
    """Reward on a grid of cells: rows along the track (every `ds` metres), columns across it (left border to
    right border, with a margin beyond each). `corner_x/y` are the cell corners for `pcolormesh`."""

    track: Track
    reward: np.ndarray  # (stations, across)
    corner_x: np.ndarray  # (stations + 1, across + 1)
    corner_y: np.ndarray
    center_x: np.ndarray  # (stations, across): where each cell's reward was evaluated
    center_y: np.ndarray
    speed: float
    heading: str
    steering: float
    problems: list[RewardProblem]
    failed: int

    def best_line(self) -> tuple[np.ndarray, np.ndarray]:
        """Per station, the cell across the width with the highest reward (NaN-safe)."""
        r = np.where(np.isfinite(self.reward), self.reward, -np.inf)
        j = np.argmax(r, axis=1)
        i = np.arange(r.shape[0])
        return self.center_x[i, j], self.center_y[i, j]

    def describe(self) -> str:
        fin = self.reward[np.isfinite(self.reward)]
        rng = f"reward {fin.min():.3g} .. {fin.max():.3g}" if fin.size else "no finite reward"
        return (f"{self.track.name}: reward at {self.speed:g} m/s, heading {self.heading}, "
                f"steering {self.steering:g}°; {rng}")


def parse_heading(spec: str) -> tuple[str, float]:
    """'along', 'against', a number of degrees added to the track direction (+ = left), or 'aim:K' (pointing
    at the centre waypoint K ahead of the next one). Returns (kind, value)."""
    spec = str(spec).strip().lower()
    if spec in ("along", "against"):
        return spec, 0.0
    if spec.startswith("aim"):
        k = spec.split(":", 1)[1] if ":" in spec else "2"
        if k.isdigit():
            return "aim", float(k)
    else:
        try:
            return "offset", float(spec)
        except ValueError:
            pass
    raise ValueError(f"heading {spec!r}: use along, against, an offset in degrees (e.g. 15 or -15) "
                     "or aim:K (towards the K-th centre waypoint ahead)")


def reward_map(reward, track: Track, *, speed: float = 2.0, heading: str = "along", steering: float = 0.0,
               ds: float = 0.05, across: int = 21, margin: float = 0.15) -> RewardMap:
    """Evaluate `reward` over the track surface: every `ds` metres along it and at `across` positions between
    the borders, plus `margin` (fraction of the width) beyond each border, with the given speed, heading rule
    (`parse_heading`) and steering. Progress is measured from the start line; steps are those of driving
    there at `speed`."""
    fn = as_reward_function(reward)
    kind, value = parse_heading(heading)
    n_s = max(int(math.ceil(track.length / ds)), 4)
    s_edges = np.linspace(0.0, track.length, n_s + 1)
    if not track.closed:
        s_edges[-1] -= 1e-9
    du = 1.0 / across
    n_m = int(math.ceil(margin / du))
    u_edges = np.linspace(-n_m * du, 1.0 + n_m * du, across + 2 * n_m + 1)
    corners = _cross_points(track, np.repeat(s_edges, u_edges.size), np.tile(u_edges, s_edges.size))
    corners = corners.reshape(s_edges.size, u_edges.size, 2)
    s_c = 0.5 * (s_edges[1:] + s_edges[:-1])
    u_c = 0.5 * (u_edges[1:] + u_edges[:-1])
    s_all = np.repeat(s_c, u_c.size)
    pts = _cross_points(track, s_all, np.tile(u_c, s_c.size))
    head = _map_heading(track, kind, value, s_all, pts)
    progress = s_all / track.length * 100.0
    pc = params_columns(track, pts[:, 0], pts[:, 1], head, speed, steering, progress,
                        _steps_for(progress, track.length, max(speed, 0.1)))
    res = score(fn, pc)
    shape = (s_c.size, u_c.size)
    return RewardMap(track, res.rewards.reshape(shape), corners[..., 0], corners[..., 1],
                     pts[:, 0].reshape(shape), pts[:, 1].reshape(shape), float(speed), heading, float(steering),
                     res.problems, res.failed)


def _map_heading(track: Track, kind: str, value: float, s: np.ndarray, pts: np.ndarray) -> np.ndarray:
    along = np.degrees(track.heading_at(s))
    if kind == "along":
        return wrap_degrees(along)
    if kind == "against":
        return wrap_degrees(along + 180.0)
    if kind == "offset":
        return wrap_degrees(along + value)
    # aim: at the centre waypoint `value` after the next one
    nxt = np.searchsorted(track.waypoint_s, s, side="right")
    n = track.num_waypoints
    target = nxt + int(value)
    target = np.mod(target, n - 1) if track.closed else np.minimum(target, n - 1)
    d = track.center[target] - pts
    return np.degrees(np.arctan2(d[:, 1], d[:, 0]))


__all__ = ["CheckReport", "RewardMap", "States", "check_reward", "parse_heading", "reward_map", "sample_states"]
