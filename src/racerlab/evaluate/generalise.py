"""Generalisation: the share of tracks a model has never driven on which it completes a lap.

    >>> from racerlab.evaluate.generalise import held_out_tracks, evaluate_tracks
    >>> tracks = held_out_tracks("aws-tracks/", count=20, exclude=["reInvent2019_track"])
    >>> res = evaluate_tracks("my-model", tracks, trials=3)
    >>> res.share                        # 0.85: laps completed on 17 of the 20 tracks

Each track is driven `trials` times, one lap from the start line with greedy actions and no reset: the
first incident (off track, reversed, immobilised) or `MAX_LAP_SECONDS` end the trial.

A *layout* is a track's shape, whatever its name or direction: a track's `_cw` / `_ccw` files, copies under
another name (Monaco and Monaco_building), copies moved elsewhere (2022_summit_speedway and
2024_reinvent_champ) and mirror images (reInvent2019_wide and reInvent2019_wide_mirrored) are one layout
(`same_layout`: their centre lines, centred, lie within `LAYOUT_TOL_M` of each other on average). Held-out
tracks (`held_out_tracks`) are drawn only from layouts a model never trained on, and a training set
(`training_tracks`) only from layouts outside a held-out set.
A track counts as completed when at least one trial completes its lap. With `randomise` (the
`[randomise]` settings of `training.toml`) the same tracks are driven again under domain
randomisation and the result says how much the share drops.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from racerlab.errors import RacerlabError, TrackError
from racerlab.evaluate.api import car_config, load_model, make_policy
from racerlab.evaluate.rules import RaceRules
from racerlab.evaluate.runner import run_evaluation
from racerlab.spec import STEPS_PER_SECOND
from racerlab.track.core import Track, load_file

DIRECTION_SUFFIX = re.compile(r"_(ccw|cw)$")
MAX_LAP_SECONDS = 300.0  # a 90 m lap at 0.3 m/s
# Two AWS centre lines of one layout lie within 0.01 m of each other (centred); the closest distinct layouts,
# small ovals of ~20 m, 0.24 m apart (Mexico_track and Tokyo_Training_track mirrored); reinvent_base and its
# wider redraw reInvent2019_wide 0.17 m, counted as one layout
LAYOUT_TOL_M = 0.2
LAYOUT_POINTS = 300  # centre-line points compared


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


class Layout:
    """A track's layout: `LAYOUT_POINTS` points evenly spaced along its centre line, centred on their mean (with
    their nearest-neighbour trees, built once)."""

    FLIPS = ((1.0, 1.0), (-1.0, 1.0), (1.0, -1.0))  # as it is, mirrored left-right, mirrored top-bottom

    def __init__(self, track):
        c = np.asarray(track.center, dtype=np.float64)
        if len(c) > 1 and np.allclose(c[0], c[-1]):
            c = c[:-1]
        ring = np.vstack([c, c[:1]])
        s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(ring, axis=0).T))])
        u = np.linspace(0.0, s[-1], LAYOUT_POINTS, endpoint=False)
        pts = np.stack([np.interp(u, s, ring[:, 0]), np.interp(u, s, ring[:, 1])], axis=1)
        self.points = pts - pts.mean(axis=0)
        self.lo, self.hi = self.points.min(axis=0), self.points.max(axis=0)
        self.radius = np.hypot(*self.points.T)
        self.rmin, self.rmax = float(self.radius.min()), float(self.radius.max())
        self._trees = None

    def trees(self):
        if self._trees is None:
            from scipy.spatial import cKDTree

            self._trees = [cKDTree(self.points * flip) for flip in self.FLIPS]
        return self._trees

    def gap(self, other: Layout, flip: int = 0) -> float:
        """Mean distance from each point of this layout to the nearest of `other` (mirrored by FLIPS[flip]),
        and back, averaged."""
        mine, theirs = self.trees()[0], other.trees()[flip]
        return 0.5 * (float(theirs.query(self.points)[0].mean()) +
                      float(mine.query(other.points * self.FLIPS[flip])[0].mean()))

    def near(self, other: Layout, flip: int, tol: float) -> bool:
        """gap(other, flip) < tol. A lower bound rules most pairs out first: no point is nearer to a layout than to
        its bounding box, nor than to the ring between its least and greatest distance from its centre."""
        if 0.5 * (self._outside(other, flip) + other._outside(self, flip)) >= tol:
            return False
        return self.gap(other, flip) < tol

    def _outside(self, other: Layout, flip: int) -> float:
        """Mean over this layout's points of a lower bound on their distance to `other` mirrored by FLIPS[flip]."""
        pts = self.points * self.FLIPS[flip]  # mirroring both alike keeps every distance
        box = np.hypot(*np.maximum(np.maximum(other.lo - pts, pts - other.hi), 0.0).T)
        ring = np.maximum(np.maximum(other.rmin - self.radius, self.radius - other.rmax), 0.0)
        return float(np.maximum(box, ring).mean())


def layout_shape(track) -> Layout:
    """`track`'s `Layout`."""
    return Layout(track)


def same_layout(a: Layout, b: Layout, tol: float = LAYOUT_TOL_M) -> bool:
    """Whether two layouts are one: the same shape, or its mirror image (either axis), wherever it lies and
    whichever way it is driven."""
    return any(a.near(b, k, tol) for k in range(len(Layout.FLIPS)))


def folder_layouts(folder) -> dict[str, Path]:
    """One `.npy` file per track name of `folder`, its `_cw` / `_ccw` variants folded in (the plain file, else
    the first variant)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise RacerlabError(f"{folder}: no such folder of track .npy files; give a folder that holds AWS tracks "
                            "(`racerlab tracks fetch --all` writes them)")
    layouts: dict[str, Path] = {}
    for p in sorted(folder.glob("*.npy")):
        base = DIRECTION_SUFFIX.sub("", p.stem)
        if base not in layouts or p.stem == base:
            layouts[base] = p
    return layouts


def _excluded_shapes(exclude, layouts: dict[str, Path]) -> list[Layout]:
    """The layouts of `exclude` (tracks, paths or names: a name of the folder, else any track racerlab loads)."""
    from racerlab import track as tracks

    shapes = []
    for e in exclude:
        if isinstance(e, Track):
            shapes.append(layout_shape(e))
            continue
        path, base = Path(str(e)), DIRECTION_SUFFIX.sub("", Path(str(e)).stem)
        if path.is_file():
            t = load_file(path)
        elif base in layouts:
            t = load_file(layouts[base])
        else:
            try:
                t = tracks.load(str(e))
            except TrackError as exc:
                raise RacerlabError(f"{e}: a training track that does not load ({exc}); held-out tracks must be "
                                    "checked against every track trained on") from None
        shapes.append(layout_shape(t))
    return shapes


def held_out_tracks(folder, count: int = 20, exclude=(), seed: int = 0) -> list[Path]:
    """`count` track files (.npy) of `folder` chosen at random (seeded), one per layout (`same_layout`), none of
    the layout of a track in `exclude` (the training tracks: names, paths or tracks), none open (no lap to
    complete). Fewer than `count` is an error that says how many there are."""
    layouts = folder_layouts(folder)
    banned = _excluded_shapes(exclude, layouts)
    names = sorted(layouts)
    picked, shapes = [], []
    for i in np.random.default_rng(seed).permutation(len(names)).tolist():
        if len(picked) == count:
            break
        t = load_file(layouts[names[i]])
        if not t.closed:
            continue
        shape = layout_shape(t)
        if not any(same_layout(shape, other) for other in (*banned, *shapes)):
            shapes.append(shape)
            picked.append(i)
    if len(picked) < count:
        raise RacerlabError(f"{folder}: {len(picked)} closed track layouts not excluded, fewer than the {count} "
                            "asked; lower --count or add tracks")
    return [layouts[names[i]] for i in sorted(picked)]


def training_tracks(folder, held_out, count: int | None = None, seed: int = 0) -> list[Path]:
    """Track files of `folder` to train on: one per closed layout that is not the layout of any track in
    `held_out` (paths, names or tracks), all of them or `count` chosen at random (seeded), in name order."""
    layouts = folder_layouts(folder)
    banned = _excluded_shapes(held_out, layouts)
    kept, shapes = [], []
    for name in sorted(layouts):
        t = load_file(layouts[name])
        shape = layout_shape(t) if t.closed else None
        if shape is None or any(same_layout(shape, other) for other in (*banned, *shapes)):
            continue
        shapes.append(shape)
        kept.append(layouts[name])
    if count is not None and count < len(kept):
        idx = np.random.default_rng(seed).choice(len(kept), size=count, replace=False)
        kept = [kept[i] for i in sorted(idx.tolist())]
    return kept


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
    model = load_model(model_dir, checkpoint)
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
    return TracksResult(model.folder.path.resolve().name, model.checkpoint, results[0],
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
