"""`ObjectSet`: the objects of every car of a simulator, its arrays and their parts (placement, start rule, motion,
crash rule, sensing: one module each), and `race_layout`, where a race's objects stand for pictures."""

from __future__ import annotations

import numpy as np

from racerlab.errors import ConfigError
from racerlab.sim.objects.crash import BOX_FOOTPRINT_M, CAR_FOOTPRINT_M, CrashRule
from racerlab.sim.objects.motion import BotMotion
from racerlab.sim.objects.placement import Lanes, Placement
from racerlab.sim.objects.sensing import BOX_SIZE_M, Sensing
from racerlab.sim.objects.starts import MovedStarts, StartRule
from racerlab.spec import RaceConfig
from racerlab.track import Track


class ObjectSet(Placement, StartRule, BotMotion, CrashRule, Sensing):
    """The objects of every car of a simulator: per car `m` boxes, bot cars (`bots`, driven by `advance`) or,
    in a head-to-model race (`racers`), the other car of its pair (set by `follow`), with their params.

    Arrays (car axis first): `xy` (n, m, 2), `yaw` (n, m), `arc` (n, m: centre-line projection in the car's
    driving direction, the param `objects_distance`), `dfc` (n, m), `left` (n, m).

    Its methods come from one module per subject: `placement` (`place`, `nearest`, `reset_behind`), `starts`
    (`clear_starts`), `motion` (`advance`, `follow`, `pause`), `crash` (`crashed`, `crashed_at_model_point`) and
    `sensing` (`params_columns`, `features_ahead`); this class holds the arrays they share.
    """

    def __init__(self, race: RaceConfig, track: Track, track_reversed: Track, num_cars: int, rng):
        self.race = race
        self.rng = rng
        self.lanes = (Lanes(track), Lanes(track_reversed))
        self._ccw = (track.is_ccw, track_reversed.is_ccw)
        self.bots = race.num_bot_cars > 0
        self.racers = race.head_to_model  # each car's one object is the other car of its pair
        if self.racers and num_cars % 2:
            raise ConfigError(f"{race.where}: a head_to_model race pairs the cars; use an even number of cars, "
                              f"not {num_cars}")
        m = race.num_bot_cars if self.bots else 1 if self.racers else race.num_obstacles
        self.num_objects = m
        cars = self.bots or self.racers
        foot = CAR_FOOTPRINT_M if cars else BOX_FOOTPRINT_M
        self.half = (0.5 * foot[0], 0.5 * foot[1])
        self.box_size_m = np.array(CAR_FOOTPRINT_M if cars else BOX_SIZE_M)
        self.speed = race.bot_car_speed if self.bots else 0.0
        self.rev = np.zeros(num_cars, dtype=np.bool_)
        self.xy = np.zeros((num_cars, m, 2))
        self.yaw = np.zeros((num_cars, m))
        self.arc = np.zeros((num_cars, m))
        self.dfc = np.zeros((num_cars, m))
        self.left = np.zeros((num_cars, m), dtype=np.bool_)
        self.lane = np.zeros((num_cars, m), dtype=np.int64)  # a bot's lane (the one it leaves in a lane change)
        self.order = np.zeros((num_cars, m), dtype=np.int64)  # objects sorted by `arc`
        self._lists: list = [None] * num_cars
        self._moved_starts = MovedStarts()  # (reversed, box lane, x, y) of a start near a box -> its moved pose
        # bot cars: start distance along the centre line, the bots' clock (s driven, pauses excluded), the pause
        # left after a bot rear-ended the car, the current lane change (clock times; inf: none)
        self.d0 = np.zeros((num_cars, m))
        self.clock = np.zeros(num_cars)
        self.pause_left = np.zeros(num_cars)
        self.change_start = np.full((num_cars, m), np.inf)
        self.change_end = np.full((num_cars, m), np.inf)
        # the centre-line segment each object's projection found last: the next search starts there (-1: search
        # everywhere)
        self._hint = np.full((num_cars, m), -1, dtype=np.int64)
        self._bot_cache: dict = {}
        self._no_due, self._no_draws = np.zeros((0, 2), dtype=np.int64), np.zeros(0)
        speed = self.speed
        self.change_s = race.lane_change_distance / speed if speed > 0 else np.inf
        self.lane_changes = self.bots and race.is_lane_change and speed > 0
        # fixed and evenly spaced boxes stand in the same places every episode: each direction's layout is
        # placed once and then copied, so that a reset costs microseconds instead of a millisecond per car
        self._layouts: dict | None = ({} if (race.object_positions or not race.randomize_obstacle_locations)
                                      and not (self.bots or self.racers) else None)


def race_layout(race: RaceConfig, track: Track) -> dict | None:
    """Where a race's objects stand at an episode's start, for pictures: {"kind": "box" | "bot", "xy" (m, 2),
    "yaw" (m,), "size" (length, width) m, "lane" (m,)}; None in a time trial, a head-to-model race or when the
    layout is random (re-drawn at every reset)."""
    if not race.has_objects or race.head_to_model:
        return None
    if (race.num_bot_cars and race.randomize_bot_car_locations) or \
            (race.num_obstacles and race.randomize_obstacle_locations and not race.object_positions):
        return None
    sim_objects = ObjectSet(race, track, track.reverse(), 1, np.random.default_rng(0))
    sim_objects.place(np.zeros(1, dtype=np.int64), np.zeros(1, dtype=bool))
    return {"kind": "bot" if sim_objects.bots else "box", "xy": sim_objects.xy[0].copy(),
            "yaw": sim_objects.yaw[0].copy(), "size": tuple(sim_objects.box_size_m), "lane": sim_objects.lane[0].copy()}
