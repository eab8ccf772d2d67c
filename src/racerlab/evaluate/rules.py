"""Race rules (facts §8) and where a car is put back on the track after an incident.

`RaceRules` holds the settings of an AWS evaluation worker with DRfC's defaults (3 trials,
continuous laps, 5 s off-track penalty, 100 resets). `reset_pose` is simapp's
`_get_car_reset_model_state` without obstacles: the centre-line point at the car's progress,
moved onto the nearer of the two lanes (the midlines between the centre line and each border)
and aligned with that lane.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from racerlab.errors import RacerlabError
from racerlab.spec import (
    EVAL_COLLISION_PENALTY_S,
    EVAL_MAX_RESETS,
    EVAL_MAX_RESETS_AFTER_CRASH,
    EVAL_OFF_TRACK_PENALTY_S,
    EVAL_RESET_AHEAD_DIST_M,
    EVAL_TRIALS,
    STEP_S,
)

# AWS MAX_STEPS of DeepRacerRacetrackEnv (facts §2): the step cap of one evaluation episode
AWS_MAX_EPISODE_STEPS = 100_000
# the incidents that pause the car (or end the episode once the resets are used up)
INCIDENTS = ("off_track", "crashed", "immobilized", "reversed")


@dataclass(frozen=True)
class RaceRules:
    """How an evaluation is run. Defaults are DRfC's `DR_EVAL_*` (facts §8).

    With `continuous` one episode drives `trials` laps (timing restarts at each lap-complete step);
    without it every trial is an episode of one lap from the start line. After an incident the car
    is held for the penalty (simulated seconds) and put back, `max_resets` times per episode; the
    next incident ends the episode.
    """

    trials: int = EVAL_TRIALS
    continuous: bool = True  # DR_EVAL_IS_CONTINUOUS
    off_track_penalty: float = EVAL_OFF_TRACK_PENALTY_S  # s
    collision_penalty: float = EVAL_COLLISION_PENALTY_S  # s
    reverse_penalty: float | None = None  # simapp REVERSE_PENALTY: None = the off-track penalty
    immobilized_penalty: float = 0.0  # simapp IMMOBILIZED_PENALTY
    max_resets: int = EVAL_MAX_RESETS
    reverse: bool = False  # drive the track the other way
    max_episode_steps: int = AWS_MAX_EPISODE_STEPS
    # simapp ENABLE_MERCY_RESET: the max_resets_after_crash-th consecutive crash into the same box puts the car
    # reset_ahead_dist m of centre line ahead of it (instead of behind); off unless asked (docs/objects.md)
    enable_mercy_reset: bool = False
    max_resets_after_crash: int = EVAL_MAX_RESETS_AFTER_CRASH
    reset_ahead_dist: float = EVAL_RESET_AHEAD_DIST_M  # m of centre line

    def __post_init__(self):
        if isinstance(self.trials, bool) or int(self.trials) != self.trials or self.trials < 1:
            raise RacerlabError(f"trials must be a whole number >= 1, got {self.trials!r}")
        for name in ("off_track_penalty", "collision_penalty", "reverse_penalty", "immobilized_penalty"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and 0 <= value <= 3600):
                raise RacerlabError(f"{name.replace('_', ' ')} must be between 0 and 3600 s, got {value!r}")
        if isinstance(self.max_resets, bool) or int(self.max_resets) != self.max_resets or self.max_resets < 0:
            raise RacerlabError(f"max resets must be a whole number >= 0, got {self.max_resets!r}")
        n = self.max_resets_after_crash
        if isinstance(n, bool) or int(n) != n or n < 1:
            raise RacerlabError(f"max resets after crash must be a whole number >= 1, got {n!r}")
        if not (math.isfinite(self.reset_ahead_dist) and 0 <= self.reset_ahead_dist <= 10):
            raise RacerlabError(f"reset ahead dist must be between 0 and 10 m, got {self.reset_ahead_dist!r}")
        if self.max_episode_steps < 10:
            raise RacerlabError(f"max episode steps must be >= 10, got {self.max_episode_steps!r}")

    def penalty(self, status: str) -> float:
        """Seconds a car is held after the incident `status` (an `INCIDENTS` name)."""
        if status == "off_track":
            return self.off_track_penalty
        if status == "crashed":
            return self.collision_penalty
        if status == "reversed":
            return self.off_track_penalty if self.reverse_penalty is None else self.reverse_penalty
        if status == "immobilized":
            return self.immobilized_penalty
        raise ValueError(f"not an incident: {status!r}")

    def to_json(self) -> dict:
        out = asdict(self)
        out["reverse_penalty"] = self.penalty("reversed")
        return out


def pause_steps(penalty_s: float, dt: float = STEP_S) -> int:
    """Steps a car is held for a penalty: simapp subtracts each step's sim time from the remaining
    penalty and resumes on the step where it reaches 0, so there is always at least one pause step."""
    return max(1, math.ceil(penalty_s / dt - 1e-9))


# ---- where the car is put back -------------------------------------------------------------------


class Lanes:
    """The inner and outer lanes of a track in its driving direction: midlines between the centre
    line and each border, as simapp builds `inner_lane` and `outer_lane`."""

    def __init__(self, track):
        self.track = track
        self.lines = (0.5 * (track.center + track.inner), 0.5 * (track.center + track.outer))

    def reset_pose(self, s: float, near_xy) -> tuple[float, float, float]:
        """Base pose (x, y, yaw rad) at arc length `s`: on the lane nearer to `near_xy` (the car's last
        base position on the road), heading along that lane (forward difference)."""
        c = self.track.point_at(s)
        best = None
        for lane in self.lines:
            p, yaw = project_on_polyline(lane, c)
            d = math.hypot(p[0] - near_xy[0], p[1] - near_xy[1])
            if best is None or d < best[0]:
                best = (d, float(p[0]), float(p[1]), yaw)
        return best[1], best[2], best[3]


def project_on_polyline(line: np.ndarray, point) -> tuple[np.ndarray, float]:
    """Nearest point of the polyline `line` (N, 2) to `point`, and the direction (rad) of the segment
    it lies on (the next one when it lies on a segment's end, as a forward difference would)."""
    a = line[:-1]
    d = line[1:] - a
    seg2 = np.einsum("ij,ij->i", d, d)
    rel = np.asarray(point, dtype=np.float64) - a
    t = np.clip(np.einsum("ij,ij->i", rel, d) / np.where(seg2 > 0, seg2, 1.0), 0.0, 1.0)
    foot = a + t[:, None] * d
    k = int(np.argmin(np.einsum("ij,ij->i", foot - point, foot - point)))
    k_dir = k + 1 if t[k] >= 1.0 - 1e-9 and k + 1 < len(d) else k
    while seg2[k_dir] == 0 and k_dir + 1 < len(d):  # a repeated point has no direction
        k_dir += 1
    return foot[k], math.atan2(d[k_dir, 1], d[k_dir, 0])
