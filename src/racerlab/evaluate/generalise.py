"""Generalisation: the share of tracks a model has never driven on which it completes a lap.

    >>> from racerlab.evaluate.generalise import held_out_tracks, evaluate_tracks
    >>> tracks = held_out_tracks("aws-tracks/", count=20, exclude=["reInvent2019_track"])
    >>> res = evaluate_tracks("my-model", tracks, trials=3)
    >>> res.share                        # 0.85: laps completed on 17 of the 20 tracks

Each track is driven `trials` times, one lap from the start line with greedy actions and no reset: the
first incident (off track, reversed, immobilised) or `MAX_LAP_SECONDS` end the trial.
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
from racerlab.evaluate.api import car_config, make_policy
from racerlab.evaluate.rules import RaceRules
from racerlab.evaluate.runner import run_evaluation
from racerlab.model import ModelFolder
from racerlab.spec import STEPS_PER_SECOND
from racerlab.track.core import load_file

DIRECTION_SUFFIX = re.compile(r"_(ccw|cw)$")
MAX_LAP_SECONDS = 300.0  # a 90 m lap at 0.3 m/s


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


def held_out_tracks(folder, count: int = 20, exclude=(), seed: int = 0) -> list[Path]:
    """`count` track files (.npy) of `folder` chosen at random (seeded), one per layout: a track's _cw / _ccw
    variants count as the same layout, and the names in `exclude` (e.g. the training tracks) and their
    variants are left out, and so are open tracks (no lap to complete) and copies of a layout already taken.
    Fewer than `count` is an error that says how many there are."""
    folder = Path(folder)
    if not folder.is_dir():
        raise RacerlabError(f"{folder}: no such folder of track .npy files; give a folder that holds AWS tracks "
                            "(`racerlab tracks fetch --all` writes them)")
    skip = {DIRECTION_SUFFIX.sub("", Path(str(e)).stem) for e in exclude}
    layouts: dict[str, Path] = {}
    for p in sorted(folder.glob("*.npy")):
        base = DIRECTION_SUFFIX.sub("", p.stem)
        if base not in skip and (base not in layouts or p.stem == base):
            layouts[base] = p
    names = sorted(layouts)
    picked, shapes = [], set()
    for i in np.random.default_rng(seed).permutation(len(names)).tolist():
        if len(picked) == count:
            break
        t = load_file(layouts[names[i]])
        shape = np.round(t.center, 2).tobytes()  # Monaco and Monaco_building: one layout, two names
        if t.closed and shape not in shapes:
            shapes.add(shape)
            picked.append(i)
    if len(picked) < count:
        raise RacerlabError(f"{folder}: {len(picked)} closed track layouts not excluded, fewer than the {count} "
                            "asked; lower --count or add tracks")
    return [layouts[names[i]] for i in sorted(picked)]


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
    model = ModelFolder(model_dir).open(checkpoint)
    loaded = _load_closed([t for t in tracks if not hasattr(t, "center")]) if tracks else []
    objs = [t for t in tracks if hasattr(t, "center")] + loaded
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
    return TracksResult(model.name, model.checkpoint.name, results[0],
                        results[1] if randomise is not None else [], time.perf_counter() - t0)


def _outcome(laps, name: str) -> TrackOutcome:
    times = [lap.time for lap in laps if lap.completed]
    return TrackOutcome(name, len(times), len(laps), max(lap.progress for lap in laps), min(times) if times else None)
