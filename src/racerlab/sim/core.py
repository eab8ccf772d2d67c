"""`Simulator`: many DeepRacer cars on one track, stepped together at 15 steps per simulated second.

State is struct-of-arrays with the car axis first (tables `car`, `ctr`, `meas` whose named
columns are in `racerlab.sim._kernels`); one compiled function steps every car, so no Python
runs per car in the step path. Outside `racerlab.sim` the state is read by name: `state` (the
cars now), `judged` (what the last step judged) and `trace_columns` (simtrace rows). The reward
function is not called here: `racerlab.sim.params` turns the `params` table into the AWS params
dicts when one is configured.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from racerlab.model.config import REWARD_ORDERS
from racerlab.sim import _kernels as K
from racerlab.sim.car import pack as pack_car
from racerlab.sim.car import randomised, step_lengths
from racerlab.sim.objects import FEATURE_OBJECTS, ObjectSet, RaceConfig, as_race, base_from_model_point
from racerlab.sim.state import CarState
from racerlab.spec import STEP_S, CarParams
from racerlab.track import Track
from racerlab.track import load as load_track

DEFAULT_LOOKAHEAD_M = (0.25, 0.5, 0.8, 1.2, 1.6, 2.2, 3.0)
AFTER_ACTION = REWARD_ORDERS[1]  # "after_action"; training.toml's run.reward_order names them (model.config)


@dataclass(frozen=True)
class StartRules:
    """Where training episodes start (simapp's round robin, facts §2).

    Each new episode takes the next start in one sequence shared by all cars of the simulator:
    episode k starts at `offset + k * advance` (mod 1) of the lap; with one car this is exactly
    AWS's per-worker round robin, with many it spreads the cars evenly over the lap.
    """

    change_start: bool = True
    advance: float = 0.05
    offset: float = 0.0
    reverse: bool = False
    alternate_direction: bool = False

    def __post_init__(self):
        if not 0.0 <= self.offset < 1.0 or not 0.0 <= self.advance < 1.0:
            raise ValueError("StartRules: offset and advance are fractions of the lap in [0, 1)")


class Simulator:
    """A batch of `num_cars` cars on `track`. See the module docstring of `_kernels` for the step order."""

    def __init__(self, track: Track | str, num_cars: int = 1, car: CarParams | None = None, *,
                 start: StartRules | None = None, max_episode_steps: int = 10_000, reward_order: str = "aws",
                 lookahead_m=DEFAULT_LOOKAHEAD_M, seed: int | None = None, race: RaceConfig | None = None):
        if reward_order not in REWARD_ORDERS:
            raise ValueError(f"reward_order must be one of {REWARD_ORDERS}, got {reward_order!r}")
        self.track = track if isinstance(track, Track) else load_track(track)
        self.track_reversed = self.track.reverse()
        self.num_cars = int(num_cars)
        self.car_params = car or CarParams()
        self.start_rules = start or StartRules()
        self.max_episode_steps = int(max_episode_steps)
        self.after_action = reward_order == AFTER_ACTION
        self.dt = STEP_S
        self.rng = np.random.default_rng(seed)
        self._jitter_rng = np.random.default_rng(self.rng.bit_generator.seed_seq.spawn(1)[0])
        self._dyn_rng = None  # the randomised dynamics' stream, made at the first draw
        self._dts = np.full(self.num_cars, STEP_S)
        self.lookahead = np.asarray(lookahead_m, dtype=np.float64)
        self._pack_track()
        n = self.num_cars
        self.car = np.zeros((n, K.N_CAR))
        self.ctr = np.zeros((n, K.N_CTR), dtype=np.int64)
        self.meas = np.zeros((n, K.N_MEAS))
        self.params = np.zeros((n, K.N_MEAS))
        self.truncated = np.zeros(n, dtype=np.bool_)
        self.episode_start_time = np.zeros(n)
        self.episodes_started = 0
        self.time = 0.0
        self._all = np.ones(n, dtype=np.bool_)
        self._none = np.zeros(n, dtype=np.bool_)
        self._state = CarState(self.car, self.ctr, self.meas)
        self._judged = CarState(self.car, self.ctr, self.params)
        self.race = as_race(race) or RaceConfig()
        # each car's boxes (None in a time trial: the step then runs exactly as without objects)
        self.objects = (ObjectSet(self.race, self.track, self.track_reversed, n, self.rng)
                        if self.race.has_objects else None)
        self.reset()

    # ---- track arrays for the compiled step -----------------------------------------------------
    def _pack_track(self):
        def pack(t: Track):
            # waypoint fractions over the same length the kernel divides arc lengths by: the reversed track's
            # own length can differ in the last bit, and a model point projecting exactly onto a waypoint
            # would then get the pair before it (AWS, and log re-scoring, give the pair after it)
            return (t.center, t.segment_lengths, t.waypoint_s, t.inner, t.outer, t.waypoint_s / self.track.length)

        t = self.track
        self._trk_f = pack(t)
        self._trk_r = pack(self.track_reversed)
        bs, be, y0, bh = t.road_index
        self._road = (t.road_edges, bs, be, float(y0), float(bh))
        self._wheels = self.car_params.wheel_offsets()
        self._car_arr = np.ascontiguousarray(np.tile(pack_car(self.car_params), (self.num_cars, 1)))  # per car
        self._geom = (self._trk_f, self._trk_r, self._road, self._wheels, t.closed, t.length, t.is_ccw)

    # ---- episodes ------------------------------------------------------------------------------
    def reseed(self, seed) -> None:
        """A new random stream for starts, noise and the race's random layouts and bot timings."""
        self.rng = np.random.default_rng(seed)
        self._jitter_rng = np.random.default_rng(self.rng.bit_generator.seed_seq.spawn(1)[0])
        self._dyn_rng = None  # the randomised dynamics' stream, made at the first draw
        if self.objects is not None:
            self.objects.rng = self.rng
        self.episodes_started = 0

    def reset(self, mask=None, start_ndist=None, reverse=None) -> np.ndarray:
        """Start new episodes for the cars in `mask` (all by default); returns their indices.

        Without overrides each car takes the next round-robin start (and direction); evaluation
        passes `start_ndist` (a fraction of the lap, scalar or per car) and `reverse` to place
        cars without advancing the sequence.
        """
        idx = np.flatnonzero(self._all if mask is None else np.asarray(mask, dtype=bool))
        if idx.size == 0:
            return idx
        r = self.start_rules
        if start_ndist is None:
            k = self.episodes_started + np.arange(idx.size)
            self.episodes_started += idx.size
            nd = np.mod(r.offset + (k * r.advance if r.change_start else np.zeros(idx.size)), 1.0)
            rev = np.full(idx.size, r.reverse) ^ ((k % 2 == 1) & r.alternate_direction)
        else:
            nd = np.broadcast_to(np.asarray(start_ndist, dtype=np.float64), idx.shape)
            rev = np.broadcast_to(np.asarray(r.reverse if reverse is None else reverse, dtype=bool), idx.shape)
        self.ctr[idx, K.KREV] = rev
        if self.objects is not None:
            self.objects.place(idx, rev)
        s = nd * self.track.length
        pts = np.empty((idx.size, 2))
        yaw = np.empty(idx.size)
        for flag, t in ((False, self.track), (True, self.track_reversed)):
            sel = rev == flag
            if sel.any():
                pts[sel] = t.point_at(s[sel])
                yaw[sel] = t.heading_at(s[sel])
        if self.objects is not None:
            self.objects.clear_starts(idx, rev, pts, yaw)
        K.place_many(idx, pts[:, 0].copy(), pts[:, 1].copy(), yaw, np.ascontiguousarray(nd, dtype=np.float64),
                     self.car, self.ctr, self.meas, *self._geom)
        self._draw_dynamics(idx)
        self.episode_start_time[idx] = self.time
        self._follow()
        return idx

    def _draw_dynamics(self, idx) -> None:
        """New constants for the cars `idx` starting an episode, with the car's `randomise` on."""
        if self.car_params.randomise > 0:
            if self._dyn_rng is None:
                self._dyn_rng = np.random.default_rng(self.rng.integers(2**63))
            self._car_arr[idx] = randomised(self.car_params, self._dyn_rng, len(idx))

    def _place(self, i, x, y, yaw, start_ndist):
        K.place(i, x, y, yaw, start_ndist, self.car, self.ctr, self.meas, *self._geom)

    def set_pose(self, i: int, x: float, y: float, yaw_rad: float, speed: float = 0.0, start_ndist=None,
                 reverse: bool | None = None):
        """Put car i at an arbitrary base pose, starting a new episode there (tests, analysis, evaluation)."""
        if reverse is not None:
            self.ctr[i, K.KREV] = bool(reverse)
        t = self.track_reversed if self.ctr[i, K.KREV] else self.track
        if start_ndist is None:
            start_ndist = float(t.project([[x, y]]).s[0] / t.length)
        if self.objects is not None:
            self.objects.place([i], [bool(self.ctr[i, K.KREV])])
        self._place(i, x, y, yaw_rad, start_ndist)
        self.car[i, K.CV] = speed
        self.episode_start_time[i] = self.time
        self._follow()

    def relocate(self, i: int, x: float, y: float, yaw_rad: float, progress: float | None = None) -> None:
        """Move car i to a base pose inside its current episode (steps, start and progress continue),
        stopped; used by evaluation to put a car back on the track after an off-track. With `progress`
        the new pose is measured as continuing from that progress (%) rather than the car's last."""
        if progress is not None:
            self.meas[i, K.MPROG] = progress
        K.relocate(i, x, y, yaw_rad, self.car, self.ctr, self.meas, *self._geom)
        self._follow()

    def restart_lap(self, i: int) -> None:
        """Car i's progress counts from the start line again and its reset rules start afresh, inside
        the same episode (continuous evaluation after a completed lap, as simapp does)."""
        m = self.meas[i]
        length = (self.track_reversed if self.ctr[i, K.KREV] else self.track).length
        m[K.MPROG] = K.aws_progress(m[K.MS] / length, self.car[i, K.CSTART], 0.0)
        m[K.MPROG_PREV] = 0.0
        self.ctr[i, K.KIMMOB] = 0
        self.ctr[i, K.KREVCNT] = 0

    def pause_step(self, cars) -> None:
        """A step in which no car moves and the cars in `cars` are held (an evaluation penalty): the clock
        runs on and their step counters count the step, as simapp counts pause steps."""
        self.step(0.0, 0.0, self._none)
        self.count_held(cars)

    def count_held(self, cars) -> None:
        """The cars in `cars` were held through the last step: their step counters count it (simapp)."""
        self.ctr[cars, K.KSTEPS] += 1

    # ---- stepping -----------------------------------------------------------------------------
    def step(self, steering_deg, speed, active=None) -> np.ndarray:
        """Advance every active car one step with commanded steering (°) and speed (m/s).

        Returns the status code per car (`STATUS_NAMES`); `self.params` holds what each car's
        reward function sees this step and `self.truncated` the step-cap flags.
        """
        n = self.num_cars
        steer = np.broadcast_to(np.asarray(steering_deg, dtype=np.float64), (n,))
        spd = np.broadcast_to(np.asarray(speed, dtype=np.float64), (n,))
        act = self._all if active is None else np.asarray(active, dtype=np.bool_)
        if self.car_params.step_jitter:
            self._dts = step_lengths(self._jitter_rng, n, self.car_params.simulator)
        K.step_all(act, np.ascontiguousarray(steer), np.ascontiguousarray(spd), self.car, self.ctr, self.meas,
                   self.params, self._car_arr, self._dts, self.after_action, self.max_episode_steps,
                   self.truncated, *self._geom)
        if self.objects is not None:
            if self.objects.racers:  # the other car where it was judged (stepped cars) or stands (held ones)
                x, y, yaw = self.car[:, K.CX].copy(), self.car[:, K.CY].copy(), self.car[:, K.CYAW].copy()
                p = self.params[act]
                x[act], y[act], yaw[act] = base_from_model_point(p[:, K.MX], p[:, K.MY], p[:, K.MHEADING])
                self.objects.follow(x, y, yaw)
            self._judge_crashes(act)
            self._follow()
        self.time += self.dt
        if self.objects is not None and self.objects.bots:
            self.objects.advance(np.arange(n), self.dt)
        return self.ctr[:, K.KSTATUS]

    def _follow(self) -> None:
        """Head-to-model: each car's object is the other car of its pair where it is now."""
        if self.objects is not None and self.objects.racers:
            self.objects.follow(self.car[:, K.CX], self.car[:, K.CY], self.car[:, K.CYAW])

    def _judge_crashes(self, active) -> None:
        """The crash rule on the judged pose of the stepped cars: status `crashed` where a corner of the car is
        inside an object, unless the lap was completed on that step (AWS's status order: lap_complete, crashed,
        off_track, in_progress, immobilized, reversed)."""
        codes = self.ctr[:, K.KSTATUS]
        idx = np.flatnonzero(active & (codes != K.STATUS_PREPARE) & (codes != K.LAP_COMPLETE))
        if idx.size == 0:
            return
        judged = self.objects.crashed_at_model_point(self.params, idx, self.track.length)
        if judged is None:
            return
        crash, rear = judged
        if crash.any():
            hit = idx[crash]
            self.ctr[hit, K.KSTATUS] = K.CRASHED
            self.truncated[hit] = False
        if rear.any():  # a bot ran into the car from behind: the bots pause (not the car's crash)
            self.objects.pause(idx[rear])

    def features(self, out=None, rows=None) -> np.ndarray:
        """(num_cars, feature_size) `features` observation of the current poses (float64 in `out`).

        With `rows` only those cars' rows of `out` are recomputed (after a partial reset).
        """
        buf = np.empty((self.num_cars, self.feature_size)) if out is None else out
        idx = np.arange(self.num_cars) if rows is None else np.asarray(rows, dtype=np.int64)
        K.features(idx, self.car, self.ctr, self.meas, self._trk_f, self._trk_r, self.track.closed,
                   self.track.length, self.lookahead, self._car_arr, buf)
        if self._object_features:
            self.objects.features_ahead(idx, self.car, self.meas, self.track.length, buf, self._track_features)
        return buf

    @property
    def _track_features(self) -> int:
        return 6 + 2 * len(self.lookahead)

    @property
    def _object_features(self) -> bool:
        """Boxes and bot cars add the nearest objects ahead to `features`; the other racer of a head-to-model race
        does not (models trained for a time trial race head to head with the vector they know)."""
        return self.objects is not None and not self.objects.racers

    @property
    def feature_size(self) -> int:
        """Length of the `features` vector; with boxes or bot cars it ends with the nearest objects ahead."""
        return self._track_features + (2 * FEATURE_OBJECTS if self._object_features else 0)

    # ---- views -------------------------------------------------------------------------------
    @property
    def state(self) -> CarState:
        """The cars now, by name (`state.x`, `state.speed`, `state.progress`, ...); measured fields are
        of the current pose, the one the next observation shows."""
        return self._state

    @property
    def judged(self) -> CarState:
        """Like `state`, but the measured fields are those the last step's rules and reward saw (the
        pose the observation was taken in, or the new one with `after_action`): the simtrace row."""
        return self._judged

    def trace_columns(self, cars, judged: bool = True) -> dict[str, np.ndarray]:
        """The simtrace columns the simulator knows (`TRACE_COLUMNS`) for `cars` (indices), from the
        judged pose (a step's row) or, with `judged=False`, the current one (a held car's row)."""
        cars = np.asarray(cars)
        p = (self.params if judged else self.meas)[cars]
        return {"steps": self.ctr[cars, K.KSTEPS], "X": p[:, K.MX], "Y": p[:, K.MY], "yaw": p[:, K.MHEADING],
                "steer": self.car[cars, K.CCMD_STEER], "throttle": self.car[cars, K.CCMD_SPEED],
                "all_wheels_on_track": p[:, K.MWHEELS] == 4, "progress": p[:, K.MPROG],
                "closest_waypoint": p[:, K.MCLOSEST].astype(np.int64),
                "track_len": np.full(cars.size, self.track.length), "tstamp": np.full(cars.size, self.time)}

    # shortcuts to the most used fields of `state`
    status = property(lambda self: self._state.status, doc="`state.status`: each car's last status code")
    steps = property(lambda self: self._state.steps, doc="`state.steps`")
    reversed = property(lambda self: self._state.reversed, doc="`state.reversed`")
    progress = property(lambda self: self._state.progress, doc="`state.progress`, of the current pose")

    def status_names(self, codes=None) -> list[str]:
        codes = self.status if codes is None else codes
        return [K.STATUS_NAMES[c] for c in np.asarray(codes).tolist()]

    def terminated_mask(self, codes=None) -> np.ndarray:
        c = self.status if codes is None else np.asarray(codes)
        return (c != K.IN_PROGRESS) & (c != K.STATUS_PREPARE) & (c != K.PAUSE)

    @property
    def pose(self) -> np.ndarray:
        """(num_cars, 3) base-link x, y, yaw (rad)."""
        return self.car[:, [K.CX, K.CY, K.CYAW]].copy()

    @property
    def speed(self) -> np.ndarray:
        """Actual ground speed, m/s (the reward param `speed` is the commanded one)."""
        return self.car[:, K.CV].copy()
