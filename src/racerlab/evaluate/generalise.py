"""Generalisation: the share of tracks a model has never driven on which it completes a lap.

    >>> from racerlab.evaluate.generalise import held_out_tracks, evaluate_tracks
    >>> tracks = held_out_tracks("aws-tracks/", count=20, exclude=["reInvent2019_track"])
    >>> res = evaluate_tracks("my-model", tracks, trials=3)
    >>> res.share                        # 0.85: laps completed on 17 of the 20 tracks

Held-out tracks are drawn one per layout from layouts the model never trained on (`racerlab.track.layouts`:
`held_out_tracks`, `training_tracks`; a track's `_cw`/`_ccw` files, copies and mirror images are one layout).
Each track is driven `trials` times, one lap from the start line with greedy actions and no reset: the
first incident (off track, reversed, immobilised) or `MAX_LAP_SECONDS` end the trial. A track counts as
completed when at least one trial completes its lap. With `randomise` (the
`[randomise]` settings of `training.toml`) the same tracks are driven again under domain
randomisation and the result says how much the share drops.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from racerlab.errors import TrackError
from racerlab.evaluate.api import car_config, make_policy
from racerlab.evaluate.rules import RaceRules
from racerlab.evaluate.runner import run_evaluation
from racerlab.model import ModelFolder
from racerlab.spec import STEPS_PER_SECOND
from racerlab.track.core import Track, load_file
from racerlab.track.layouts import held_out_tracks, training_tracks  # noqa: F401 - set selection, here too

MAX_LAP_SECONDS = 300.0  # a 90 m lap at 0.3 m/s


@dataclass
class TrackOutcome:
    track: str
    laps: int  # trials with a completed lap
    trials: int
    best_progress: float  # %, over the trials
    best_lap_time: float | None  # s
    lap_times: list[float] = field(default_factory=list)  # s, of the completed trials
    limit: float | None = None  # s: the track's theoretical limit for the model's car and actions (`model_limit`)
    path: np.ndarray | None = field(default=None, repr=False)  # (N, 2) base points of the trial drawn (`_shown`)

    @property
    def completed(self) -> bool:
        return self.laps > 0

    @property
    def mean_lap_time(self) -> float | None:
        return float(np.mean(self.lap_times)) if self.lap_times else None

    @property
    def ratio(self) -> float | None:
        """The mean completed lap over the track's limit (None without a lap or a limit)."""
        mean = self.mean_lap_time
        return None if mean is None or not self.limit else mean / self.limit

    def row(self) -> dict:
        def r(x, nd):
            return None if x is None else round(x, nd)

        return {"track": self.track, "laps": self.laps, "trials": self.trials,
                "best_progress": round(self.best_progress, 2), "best_lap_time": r(self.best_lap_time, 3),
                "mean_lap_time": r(self.mean_lap_time, 3), "lap_times": [round(t, 3) for t in self.lap_times],
                "limit": r(self.limit, 3), "ratio_to_limit": r(self.ratio, 3)}


@dataclass
class TracksResult:
    """Lap completion of one model over several tracks (and under randomisation, when asked)."""

    model: str
    checkpoint: str
    tracks: list[TrackOutcome]
    randomised: list[TrackOutcome] = field(default_factory=list)
    wall_seconds: float = 0.0
    track_objects: list = field(default_factory=list, repr=False)  # the `Track`s driven, in `tracks`' order

    @staticmethod
    def _share(outcomes) -> float | None:
        return sum(o.completed for o in outcomes) / len(outcomes) if outcomes else None

    @property
    def share(self) -> float:
        return self._share(self.tracks)

    @property
    def randomised_share(self) -> float | None:
        return self._share(self.randomised)

    @property
    def drop(self) -> float | None:
        """Share of tracks completed without randomisation minus with it (None when not run randomised)."""
        return None if not self.randomised else self.share - self.randomised_share

    @staticmethod
    def mean_ratio(outcomes) -> float | None:
        """The mean over lapped tracks with a limit of their mean lap over the limit."""
        ratios = [o.ratio for o in outcomes if o.ratio is not None]
        return float(np.mean(ratios)) if ratios else None

    def to_json(self) -> dict:
        def ratio(outcomes):
            m = self.mean_ratio(outcomes)
            return None if m is None else round(m, 4)

        return {"model": self.model, "checkpoint": self.checkpoint, "tracks": len(self.tracks),
                "share_completed": self.share, "randomised_share_completed": self.randomised_share,
                "drop_under_randomisation": self.drop, "mean_ratio_to_limit": ratio(self.tracks),
                "randomised_mean_ratio_to_limit": ratio(self.randomised), "wall_seconds": round(self.wall_seconds, 2),
                "per_track": [o.row() for o in self.tracks], "per_track_randomised": [o.row() for o in self.randomised]}

    def report(self) -> str:
        lines = [f"{self.model} ({self.checkpoint}): laps completed on {sum(o.completed for o in self.tracks)} of "
                 f"{len(self.tracks)} tracks ({self.share:.0%}){self._ratio_note(self.tracks)}"]
        if self.randomised:
            lines.append(f"under randomisation: {sum(o.completed for o in self.randomised)} of {len(self.randomised)} "
                         f"({self.randomised_share:.0%}), a drop of {self.drop:.0%}{self._ratio_note(self.randomised)}")
        head = f"  {'track':<30} {'limit':>7}  {'laps':>5} {'mean lap':>9} {'x limit':>8}"
        lines.append(head + (f"  {'randomised':>10} {'mean lap':>9} {'x limit':>8}" if self.randomised else ""))
        for k, o in enumerate(self.tracks):
            laps = f"{o.laps}/{o.trials}"
            line = f"  {o.track:<30} {_fmt(o.limit, 's'):>7}  {laps:>5} {_lap(o):>9} {_fmt(o.ratio, 'x'):>8}"
            if self.randomised:
                r = self.randomised[k]
                line += f"  {f'{r.laps}/{r.trials}':>10} {_lap(r):>9} {_fmt(r.ratio, 'x'):>8}"
            lines.append(line)
        return "\n".join(lines)

    def _ratio_note(self, outcomes) -> str:
        m = self.mean_ratio(outcomes)
        return "" if m is None else f"; mean lap {m:.3f}x the limit over the tracks lapped"


def _fmt(x, unit: str) -> str:
    if x is None:
        return "-"
    return f"{x:.3f}x" if unit == "x" else f"{x:.2f} s"


def _lap(o: TrackOutcome) -> str:
    return f"{o.mean_lap_time:.2f} s" if o.lap_times else f"{o.best_progress:.0f} %"


def _load_closed(paths) -> list:
    tracks = []
    for p in paths:
        t = load_file(p)
        if not t.closed:
            raise TrackError(f"{p}: an open track (no lap to complete); leave it out")
        tracks.append(t)
    return tracks


def evaluate_tracks(model_dir, tracks, trials: int = 1, checkpoint: str | int = "best", randomise=None,
                    device: str = "cpu", seed: int = 0, on_track=None, plain=None,
                    limits: bool = False) -> TracksResult:
    """Drive the model on each track (paths or `Track`s); see the module docstring. `randomise` is a
    `RandomiseSettings` (or its dict) to run everything a second time under; `plain` the settings of the
    first pass (None; or e.g. the physical car's speed mapping alone). `on_track(outcome, randomised)` is
    called as each track is done. With `limits`, each outcome carries its track's theoretical limit for the
    model's car and actions (`model_limit`) and its mean lap over it."""
    from racerlab.sim import StartRules, World

    t0 = time.perf_counter()
    model = ModelFolder(model_dir).open(checkpoint)
    loaded = _load_closed([t for t in tracks if not isinstance(t, Track)]) if tracks else []
    objs = [t for t in tracks if isinstance(t, Track)] + loaded
    rules = RaceRules(trials=trials, continuous=False, max_resets=0,
                      max_episode_steps=int(MAX_LAP_SECONDS * STEPS_PER_SECOND))
    runs = [plain, randomise] if randomise is not None else [plain]
    results: list[list[TrackOutcome]] = [[] for _ in runs]
    car = car_config(model)  # the model's [car]
    limit_of = model_limit(car, model.metadata.actions) if limits else None
    for track in objs:
        limit = limit_of(track) if limit_of else None
        for k, r in enumerate(runs):
            world = World(track, 1, model.metadata, None, model.observation, start=StartRules(),
                          max_episode_steps=rules.max_episode_steps, seed=seed, randomise=r, car=car,
                          look=model.look)
            outcome = _outcome(run_evaluation(world, make_policy(model, world, device), rules), track.name)
            outcome.limit = limit
            results[k].append(outcome)
            if on_track is not None:
                on_track(outcome, k == 1)
    return TracksResult(model.name, model.checkpoint.name, results[0],
                        results[1] if randomise is not None else [], time.perf_counter() - t0, objs)


def _outcome(run, name: str) -> TrackOutcome:
    laps = run.laps
    times = [lap.time for lap in laps if lap.completed]
    return TrackOutcome(name, len(times), len(laps), max(lap.progress for lap in laps), min(times) if times else None,
                        times, path=_shown(run))


def _shown(run) -> np.ndarray:
    """The base points of the trial a picture shows: the first completed lap, else the one that got furthest."""
    ends = np.cumsum([lap.rows for lap in run.laps])
    starts = ends - np.array([lap.rows for lap in run.laps])
    done = [k for k, lap in enumerate(run.laps) if lap.completed]
    k = done[0] if done else int(np.argmax([lap.progress for lap in run.laps]))
    xy = np.stack([run.extra["base_x"], run.extra["base_y"]], axis=1)
    return xy[starts[k]:ends[k]]


# ---- the tracks' limits ------------------------------------------------------------------------------------

def model_limit(car, actions):
    """A function giving a track's theoretical limit (s, `racerlab line`'s `theoretical_limit`) for `car` driven
    within `actions`' steering and top speed, kept in the user's cache folder (a limit takes 2-12 s to solve)."""
    from dataclasses import replace

    lim = car
    top, steer = getattr(actions, "top_speed", None), _max_steering(actions)
    if top is not None and top < car.max_speed_mps:
        lim = replace(lim, max_speed_mps=float(top))
    if steer is not None and steer < car.max_steer_deg:
        lim = replace(lim, max_steer_deg=float(steer))
    cache = _LimitCache(lim)
    return cache.limit


def _max_steering(actions) -> float | None:
    if hasattr(actions, "steering_low"):
        return max(abs(actions.steering_low), abs(actions.steering_high))
    if hasattr(actions, "steering_deg"):
        return float(np.max(np.abs(actions.steering_deg)))
    return None


class _LimitCache:
    """Theoretical limits of one car by track (its waypoints' bytes), on disk in `limits.json` of racerlab's cache
    folder (`$RACERLAB_CACHE_DIR`, else `$XDG_CACHE_HOME/racerlab`, else `~/.cache/racerlab`)."""

    def __init__(self, car):
        self.car = car
        self.path = _cache_root() / "limits.json"

    def key(self, track) -> str:
        import hashlib

        h = hashlib.sha256(np.ascontiguousarray(track.as_array(), dtype=np.float64).tobytes())
        h.update(repr(self.car).encode())
        return h.hexdigest()[:32]

    def limit(self, track) -> float | None:
        """The limit, or None where the line solver finds no path at the off-track rule's margin (borders that fold:
        Tokyo_Training_track)."""
        from racerlab.line import theoretical_limit

        key, known = self.key(track), self._read()
        if key in known:
            return known[key]
        try:
            value = float(theoretical_limit(track, car=self.car).lap_time)
        except TrackError:
            value = None
        self._write({**self._read(), key: value})
        return value

    def _read(self) -> dict:
        import json

        try:
            return json.loads(self.path.read_text())
        except (OSError, ValueError):
            return {}

    def _write(self, data: dict) -> None:
        from racerlab.logs import atomic_write_json

        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_json(self.path, data)
        except OSError:
            pass  # a read-only cache costs only the time to solve again


def _cache_root() -> Path:
    import os

    if os.environ.get("RACERLAB_CACHE_DIR"):
        return Path(os.environ["RACERLAB_CACHE_DIR"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "racerlab"


# ---- the picture -------------------------------------------------------------------------------------------

LAPPED_COLOR = "#2ca02c"
MISSED_COLOR = "#d62728"


def save_picture(result: TracksResult, path, columns: int = 5, randomised: bool = False) -> Path:
    """One panel per track: the road, the path of the trial shown (`_shown`; green where it lapped, red where it
    left the road, with a cross at the end) and a title with its laps and mean lap over the limit."""
    from matplotlib.figure import Figure

    from racerlab.track.plot import draw_track

    outcomes = result.randomised if randomised else result.tracks
    n = len(outcomes)
    rows = max(1, -(-n // columns))
    fig = Figure(figsize=(3.2 * min(columns, n), 3.0 * rows))
    for k, (o, t) in enumerate(zip(outcomes, result.track_objects, strict=True)):
        ax = fig.add_subplot(rows, min(columns, n), k + 1)
        draw_track(t, ax, waypoint_numbers=False, title=False, legend=False)
        color = LAPPED_COLOR if o.completed else MISSED_COLOR
        if o.path is not None and len(o.path):
            ax.plot(*o.path.T, color=color, lw=1.3, zorder=6)
            if not o.completed:
                ax.plot(*o.path[-1], marker="x", color=color, ms=9, mew=2.5, zorder=7)
        how = f"{o.ratio:.2f}x limit" if o.ratio else (f"{o.mean_lap_time:.2f} s" if o.lap_times
                                                       else f"off at {o.best_progress:.0f} %")
        ax.set_title(f"{o.track}\n{o.laps}/{o.trials} laps, {how}", fontsize=8, color=color)
        ax.set_xlabel("")
        ax.set_ylabel("")
        ax.tick_params(labelsize=5)
    which = "under randomisation" if randomised else "plain"
    fig.suptitle(f"{result.model} ({result.checkpoint}) on tracks it never trained on, {which}: "
                 f"{sum(o.completed for o in outcomes)} of {n} lapped", fontsize=11)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path
