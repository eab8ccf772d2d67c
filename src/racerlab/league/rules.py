"""A race's frozen rules: what every submission is raced under, as canonical JSON with its SHA-256 hash.

`Rules` holds what decides a result (track and direction, the hidden evaluation track, race type and objects,
timing method and laps, penalties, resets, time cap, the car, the seed, the video); the schedule (open and close
times, submissions per racer) lives on the race row, because it alone may change once a race is open. Tracks are
pinned by content: the geometry is stored in the league folder under its hash, and the rules name the hash, so a
result says exactly which road it was driven on.

Timing methods (DRoA's): `best_lap` (the fastest completed lap, ranked with at least `min_laps` completed),
`average_lap` (the best mean over `min_laps` consecutive completed laps), `total_time` (every lap's time added,
ranked only when all `laps` are completed; `min_laps` = `laps`). Penalties are inside the lap times: the car is
held for them in simulated time.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field, fields, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from racerlab.errors import RacerlabError
from racerlab.league.store import LeagueError
from racerlab.spec import DEFAULT_SIMULATOR, SIMULATORS, STEPS_PER_SECOND, RaceConfig

RULES_FORMAT = "racerlab.league.rules/1"
RACE_TYPES = ("time_trial", "object_avoidance", "head_to_bot")
TIMINGS = ("best_lap", "average_lap", "total_time")
MAX_LAPS = 20
MAX_TIME_CAP_S = 1800.0


@dataclass(frozen=True)
class Rules:
    """What a race's results depend on. `race` is the objects' [race] table (DRfC's names, `spec.RaceConfig`)."""

    track: str  # the name racers are told to train on
    track_sha256: str
    eval_track: str = ""  # the track the evaluation drives when it is not the advertised one (hidden from racers)
    eval_track_sha256: str = ""
    reverse: bool = False
    race_type: str = "time_trial"
    timing: str = "best_lap"
    laps: int = 3
    min_laps: int = 1
    off_track_penalty: float = 3.0  # s (DRoA's UI: 1-3 s; the League used 2-10 s)
    collision_penalty: float = 5.0  # s
    max_resets: int = 10_000  # DRoA: effectively unlimited
    time_cap_s: float = 180.0  # the League's 3 minutes (2023-24)
    race: dict = field(default_factory=dict)
    car: str = DEFAULT_SIMULATOR
    seed: int = 0
    video: bool = True

    def __post_init__(self):
        check_rules(self)

    # ---- canonical form ----------------------------------------------------------------------------------
    def to_json(self) -> dict:
        return {"format": RULES_FORMAT, **asdict(self)}

    def canonical(self) -> str:
        """Sorted keys, no spaces, floats as Python writes them: equal rules give equal text on every machine."""
        return json.dumps(self.to_json(), sort_keys=True, separators=(",", ":"), allow_nan=False)

    @property
    def hash(self) -> str:
        return hashlib.sha256(self.canonical().encode()).hexdigest()

    @classmethod
    def from_json(cls, data: dict | str) -> Rules:
        if isinstance(data, str):
            data = json.loads(data)
        if data.get("format") != RULES_FORMAT:
            raise LeagueError(f"rules of format {data.get('format')!r}; this racerlab reads {RULES_FORMAT!r}")
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in known})

    def public_json(self) -> dict:
        """The rules as racers see them: the hidden evaluation track left out (its hash stays in the rules hash)."""
        out = self.to_json()
        if self.eval_track:
            out["eval_track"], out["eval_track_sha256"] = "hidden", ""
        return out

    # ---- for the evaluation ------------------------------------------------------------------------------
    @property
    def driven_track(self) -> tuple[str, str]:
        """(name, sha256) of the track the evaluation drives."""
        return (self.eval_track, self.eval_track_sha256) if self.eval_track else (self.track, self.track_sha256)

    def race_rules(self):
        """The `evaluate.RaceRules` of this race: continuous laps, its penalties and resets, the cap as steps."""
        from racerlab.evaluate import RaceRules

        return RaceRules(trials=self.laps, continuous=True, off_track_penalty=self.off_track_penalty,
                         collision_penalty=self.collision_penalty, max_resets=self.max_resets, reverse=self.reverse,
                         max_episode_steps=math.ceil(self.time_cap_s * STEPS_PER_SECOND - 1e-9))

    def race_config(self) -> RaceConfig:
        return RaceConfig.from_mapping({**self.race, "type": self.race_type}, where="race rules")

    def describe(self) -> str:
        """One line: "reInvent2019_track, time trial, best lap of 3 laps (1 completed needed), off-track +3 s"."""
        timing = {"best_lap": f"best lap of {self.laps} laps ({self.min_laps} completed needed)",
                  "average_lap": f"best average over {self.min_laps} laps in a row of {self.laps}",
                  "total_time": f"total time of {self.laps} laps"}[self.timing]
        objects = ""
        cfg = self.race_config()
        if cfg.num_obstacles:
            objects = f", {cfg.num_obstacles} boxes" + (" (fixed)" if cfg.object_positions else " (from the seed)")
        if cfg.num_bot_cars:
            objects = f", {cfg.num_bot_cars} bot cars at {cfg.bot_car_speed:g} m/s"
        direction = ", reversed" if self.reverse else ""
        return (f"{self.track}{direction}, {self.race_type.replace('_', ' ')}{objects}, {timing}, "
                f"off-track +{self.off_track_penalty:g} s")


def check_rules(r: Rules) -> None:
    """One-line errors for rules a race cannot run."""
    if r.race_type not in RACE_TYPES:
        raise LeagueError(f"race type {r.race_type!r}: use one of {', '.join(RACE_TYPES)}")
    if r.timing not in TIMINGS:
        raise LeagueError(f"timing {r.timing!r}: use one of {', '.join(TIMINGS)}")
    if r.car not in SIMULATORS:
        raise LeagueError(f"car {r.car!r}: use one of {', '.join(SIMULATORS)}")
    _check_laps(r)
    _check_times(r)
    _check_objects(r)


def _check_laps(r: Rules) -> None:
    for name, value in (("laps", r.laps), ("min laps", r.min_laps), ("max resets", r.max_resets),
                        ("seed", r.seed)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise LeagueError(f"{name} must be a whole number >= 0, got {value!r}")
    if not 1 <= r.laps <= MAX_LAPS:
        raise LeagueError(f"laps must be between 1 and {MAX_LAPS}, got {r.laps}")
    if not 1 <= r.min_laps <= r.laps:
        raise LeagueError(f"min laps must be between 1 and the race's {r.laps} laps, got {r.min_laps}")
    if r.timing == "total_time" and r.min_laps != r.laps:
        raise LeagueError(f"a total-time race ranks only runs of all its laps: min laps must equal laps ({r.laps})")


def _check_times(r: Rules) -> None:
    for name in ("off_track_penalty", "collision_penalty"):
        v = getattr(r, name)
        if isinstance(v, bool) or not isinstance(v, int | float) or not (math.isfinite(v) and 0 <= v <= 60):
            raise LeagueError(f"{name.replace('_', ' ')} must be between 0 and 60 s, got {v!r}")
    if not (isinstance(r.time_cap_s, int | float) and math.isfinite(r.time_cap_s)
            and 10 <= r.time_cap_s <= MAX_TIME_CAP_S):
        raise LeagueError(f"time cap must be between 10 and {MAX_TIME_CAP_S:g} s, got {r.time_cap_s!r}")


def _check_objects(r: Rules) -> None:
    if not isinstance(r.race, dict) or "type" in r.race:
        raise LeagueError("race objects: a table of [race] keys without 'type' (the race type is its own rule)")
    try:
        cfg = RaceConfig.from_mapping({**r.race, "type": r.race_type}, where="race objects")
    except RacerlabError as exc:
        raise LeagueError(str(exc)) from None
    if r.race_type == "object_avoidance" and not cfg.num_obstacles:
        raise LeagueError("an object-avoidance race needs boxes: give a number of obstacles (1-6) or their positions")
    if r.race_type == "head_to_bot" and not cfg.num_bot_cars:
        raise LeagueError("a head-to-bot race needs bot cars: give a number of bot cars (1-6)")
    if cfg.num_obstacles > 6 or cfg.num_bot_cars > 6:
        raise LeagueError("a race has at most 6 boxes or 6 bot cars (DRoA's and the League's limit)")


def objects_table(race_type: str, obstacles: int = 0, positions=(), bots: int = 0, bot_speed: float = 0.5,
                  lane_change: bool = False) -> dict:
    """The [race] table of a race's objects from the options a facilitator gives. Boxes without positions are
    drawn from the race's seed (one layout for every racer: the evaluation's world is seeded with it)."""
    if race_type == "object_avoidance":
        table = {"number_of_obstacles": int(obstacles or len(positions))}
        if positions:
            table["object_positions"] = [list(p) for p in positions]
        else:
            table["randomize_obstacle_locations"] = True
        return table
    if race_type == "head_to_bot":
        return {"number_of_bot_cars": int(bots), "bot_car_speed": float(bot_speed), "is_lane_change": bool(lane_change)}
    return {}


# ---- tracks, pinned by content ------------------------------------------------------------------------------
def track_array_hash(arr: np.ndarray) -> str:
    a = np.ascontiguousarray(arr, dtype=np.float64)
    return hashlib.sha256(f"{a.shape}".encode() + a.tobytes()).hexdigest()


def pin_track(tracks_dir: Path, name_or_path) -> tuple[str, str]:
    """Copy a bundled, AWS or uploaded track into the league's tracks folder under its content hash: (its name,
    the hash). The copy is what every evaluation of the race drives, whatever happens to the original."""
    from racerlab import track as tracks
    from racerlab.logs import atomic_write_bytes

    try:
        t = tracks.load(name_or_path)
    except RacerlabError as exc:
        raise LeagueError(str(exc)) from None
    arr = np.ascontiguousarray(t.as_array(), dtype=np.float64)
    sha = track_array_hash(arr)
    dest = tracks_dir / f"{sha}.npy"
    if not dest.is_file():
        import io

        buf = io.BytesIO()
        np.save(buf, arr, allow_pickle=False)
        atomic_write_bytes(dest, buf.getvalue())
    return t.name, sha


def load_pinned(tracks_dir: Path, name: str, sha: str):
    """The pinned track `sha` (named `name`), checked against its hash. A process keeps the last few it loaded:
    one Track object per track, so that the camera's raster of it (cached per Track) is built once per worker."""
    return _load_pinned(str(tracks_dir), name, sha)


@lru_cache(maxsize=8)
def _load_pinned(tracks_dir: str, name: str, sha: str):
    from racerlab.track import from_array

    path = Path(tracks_dir) / f"{sha}.npy"
    if not path.is_file():
        raise LeagueError(f"{path}: the race's track {name} is missing from the league folder; restore the folder "
                          "from a backup", 500)
    arr = np.load(path, allow_pickle=False)
    if track_array_hash(arr) != sha:
        raise LeagueError(f"{path}: the track {name} does not match its hash; the league folder was changed", 500)
    return from_array(arr, name=name, source=str(path))


def with_tracks(rules: Rules, tracks_dir: Path, track, eval_track=None) -> Rules:
    """`rules` with the advertised track (and the hidden evaluation track, if any) pinned in `tracks_dir`."""
    name, sha = pin_track(tracks_dir, track)
    out = replace(rules, track=name, track_sha256=sha)
    if eval_track:
        ename, esha = pin_track(tracks_dir, eval_track)
        out = replace(out, eval_track=ename, eval_track_sha256=esha)
    return out
