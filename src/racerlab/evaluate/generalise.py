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

    @property
    def completed(self) -> bool:
        return self.laps > 0


@dataclass
class TracksResult:
    """Lap completion of one model over several tracks (and under randomisation, when asked)."""

    model: str
    checkpoint: str
    tracks: list[TrackOutcome]
    randomised: list[TrackOutcome] = field(default_factory=list)
    wall_seconds: float = 0.0

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

    def to_json(self) -> dict:
        def rows(outcomes):
            return [{"track": o.track, "laps": o.laps, "trials": o.trials, "best_progress": round(o.best_progress, 2),
                     "best_lap_time": o.best_lap_time} for o in outcomes]

        return {"model": self.model, "checkpoint": self.checkpoint, "tracks": len(self.tracks),
                "share_completed": self.share, "randomised_share_completed": self.randomised_share,
                "drop_under_randomisation": self.drop, "wall_seconds": round(self.wall_seconds, 2),
                "per_track": rows(self.tracks), "per_track_randomised": rows(self.randomised)}

    def report(self) -> str:
        lines = [f"{self.model} ({self.checkpoint}): laps completed on {sum(o.completed for o in self.tracks)} of "
                 f"{len(self.tracks)} tracks ({self.share:.0%})"]
        if self.randomised:
            lines.append(f"under randomisation: {sum(o.completed for o in self.randomised)} of {len(self.randomised)} "
                         f"({self.randomised_share:.0%}), a drop of {self.drop:.0%}")
        for k, o in enumerate(self.tracks):
            r = f"  randomised {self.randomised[k].laps}/{o.trials}" if self.randomised else ""
            lap = f", best {o.best_lap_time:.2f} s" if o.best_lap_time else ""
            lines.append(f"  {o.track:<32} {o.laps}/{o.trials} laps, best progress {o.best_progress:.0f} %{lap}{r}")
        return "\n".join(lines)


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
                    device: str = "cpu", seed: int = 0, on_track=None, plain=None) -> TracksResult:
    """Drive the model on each track (paths or `Track`s); see the module docstring. `randomise` is a
    `RandomiseSettings` (or its dict) to run everything a second time under; `plain` the settings of the
    first pass (None; or e.g. the physical car's speed mapping alone). `on_track(outcome, randomised)` is
    called as each track is done."""
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
    for track in objs:
        for k, r in enumerate(runs):
            world = World(track, 1, model.metadata, None, model.observation, start=StartRules(),
                          max_episode_steps=rules.max_episode_steps, seed=seed, randomise=r, car=car,
                          look=model.look)
            outcome = _outcome(run_evaluation(world, make_policy(model, world, device), rules).laps, track.name)
            results[k].append(outcome)
            if on_track is not None:
                on_track(outcome, k == 1)
    return TracksResult(model.folder.path.resolve().name, model.checkpoint, results[0],
                        results[1] if randomise is not None else [], time.perf_counter() - t0)


def _outcome(laps, name: str) -> TrackOutcome:
    times = [lap.time for lap in laps if lap.completed]
    return TrackOutcome(name, len(times), len(laps), max(lap.progress for lap in laps), min(times) if times else None)
