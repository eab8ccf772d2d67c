"""Driving one car under race rules: laps, timing, penalties and resets as an AWS evaluation worker.

`run_evaluation(world, policy, rules)` drives car 0 of a one-car `racerlab.sim.World`
with `policy(obs) -> actions` (greedy for a model) and returns the laps and every step as simtrace
columns. What happens, following simapp (facts §2, §8):

- every episode starts on the start line (centre line) and begins with the prepare step;
- a lap is complete on the step whose judged progress reaches 100 %; its time is the simulated time
  from the episode's reset (or, in continuous mode, from the previous lap-complete step) to the end of
  that step, so held penalty time is included;
- continuous mode drives all trials in one episode; at each lap-complete step progress restarts from
  the start line and the immobilized/reversed counters are cleared, as simapp resets its metrics and
  reset rules there. Like AWS's logs, the row that completes a lap other than the episode's last says
  `in_progress` at progress 100 (done False); only the last says `lap_complete`. (On an open track
  every trial is its own episode.)
- an incident (off track, reversed, immobilized, crash) pauses the car while resets remain: the
  incident's row carries the penalty in `pause_duration`; the car is put on the nearer lane at the
  previous step's progress (`Lanes.reset_pose`), stopped, and held for the penalty as simulated time:
  `pause_steps(penalty)` rows with status `pause`, reward 0 and the remaining penalty; then it drives on.
  After `max_resets` resets in an episode the next incident ends it.

The held car is simply not stepped (inactive in the simulator, whose clock runs on), and its step
counter is advanced by hand because simapp counts pause steps too.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from racerlab.evaluate.results import Lap
from racerlab.evaluate.rules import INCIDENTS, Lanes, RaceRules, pause_steps, project_on_polyline
from racerlab.logs import SIMTRACE_COLUMNS
from racerlab.sim import STATUS_NAMES, Status
from racerlab.sim.objects import RESET_BEHIND_DIST_M
from racerlab.spec import MODEL_POINT_AHEAD_M, STEP_S

# per-row values kept beside the simtrace for videos and checks: the car's base pose and ground
# speed after the step, and the running lap clock (s since the lap started)
EXTRA_COLUMNS = ("base_x", "base_y", "base_yaw", "speed", "lap_clock")


@dataclass
class EvalRun:
    """What one evaluation drove: the laps, the simtrace columns and the per-row extras."""

    laps: list[Lap]
    trace: dict[str, np.ndarray]  # the 19 AWS simtrace columns
    extra: dict[str, np.ndarray]  # EXTRA_COLUMNS
    frames: list | None = None  # the observation's camera image per row, when asked for
    wall_seconds: float = 0.0
    dt: float = STEP_S
    # the race's objects as the car saw them, per row, when frames were kept: {"pose": [(m, 3) x, y, yaw], "size":
    # (length, width) m, "cars": bot cars or the other racer (not boxes)}
    objects: dict | None = None
    # boxes or bot cars: where they stood at the start of each sim episode (`_Driver.layouts`), for the report
    layouts: dict | None = None

    @property
    def rows(self) -> int:
        return int(self.trace["steps"].size)


class _Trace:
    """Rows appended one at a time (an evaluation is a few thousand steps), then turned into arrays."""

    def __init__(self):
        self.cols: dict[str, list] = {c: [] for c in (*SIMTRACE_COLUMNS, *EXTRA_COLUMNS)}

    def __len__(self) -> int:
        return len(self.cols["steps"])

    def add(self, values: dict) -> None:
        for k, v in values.items():
            self.cols[k].append(v)

    def set_last(self, key: str, value) -> None:
        self.cols[key][-1] = value

    def last(self, key: str):
        return self.cols[key][-1]

    def arrays(self, continuous_actions: bool) -> tuple[dict, dict]:
        trace = {c: np.asarray(self.cols[c]) for c in SIMTRACE_COLUMNS if c != "action"}
        act = self.cols["action"]
        trace["action"] = np.asarray(act, dtype=np.float64).reshape(-1, 2) if continuous_actions \
            else np.asarray(act, dtype=np.int64)
        trace = {c: trace[c] for c in SIMTRACE_COLUMNS}
        extra = {c: np.asarray(self.cols[c], dtype=np.float64) for c in EXTRA_COLUMNS}
        return trace, extra


@dataclass
class _Episode:
    laps_left: int
    lap_start: float  # simulated time the current lap started
    first_row: int  # trace row where the current lap starts
    resets: int = 0
    counts: dict = field(default_factory=lambda: dict.fromkeys(INCIDENTS, 0))
    prev: tuple | None = None  # (progress, model x, model y, heading °) of the previous row
    obstacle_crashes: int = 0  # the simtrace's obstacle_crash_counter
    last_box: int = -1  # the box of the last obstacle crash, and how many crashes in a row were into it
    same_box_crashes: int = 0


def observation_row(obs, i: int):
    """Car i's observation as a batch of one (arrays, or dicts / tuples of them)."""
    if isinstance(obs, dict):
        return {k: observation_row(v, i) for k, v in obs.items()}
    if isinstance(obs, tuple):
        return tuple(observation_row(v, i) for v in obs)
    return obs[i:i + 1]


class _Driver:
    """One car (`car`, 0 by default) of `world` under race rules: a step is `act` (the policy's action), the
    world's step, then `after` (the row, laps and incidents); a held car's steps are pause rows."""

    def __init__(self, world, policy: Callable, rules: RaceRules, keep_frames: bool,
                 image_of: Callable | None, on_lap: Callable | None, car: int = 0):
        self.world = world
        self.sim = world.sim
        self.i = car
        self.car = np.array([car], dtype=np.int64)  # the car, as an index array
        self.active = np.zeros(self.sim.num_cars, dtype=bool)
        self.active[car] = True
        self.hold: tuple | None = None  # (steps left, penalty, steps done, obs, actions) while held
        self.policy = policy
        self.rules = rules
        self.track = self.sim.track_reversed if rules.reverse else self.sim.track
        self.lanes = Lanes(self.track)
        self.trace = _Trace()
        self.laps: list[Lap] = []
        self.frames = [] if keep_frames else None
        self.object_poses = [] if keep_frames and self.sim.objects is not None else None
        self.image_of = image_of
        self.on_lap = on_lap
        self.discrete = world.discrete
        self.ep: _Episode | None = None
        self.layouts: list[dict] = []

    # ---- episodes -----------------------------------------------------------------------------
    def run(self) -> None:
        if self.rules.continuous and self.track.closed:
            self._episode(self.rules.trials)
        else:
            for _ in range(self.rules.trials):
                self._episode(1)

    def _episode(self, laps: int) -> None:
        sim = self.sim
        sim.reset(start_ndist=0.0, reverse=self.rules.reverse)
        self.begin(laps)
        while not self._step():
            pass
        self.finish()

    def begin(self, laps: int) -> None:
        """A new episode of `laps` laps from where the car was just reset."""
        self.ep = _Episode(laps_left=laps, lap_start=self.sim.time, first_row=len(self.trace))
        self.hold = None
        o = self.sim.objects
        if o is not None and not o.racers:  # the episode's layout (bots: where they start), as placed at the reset
            self.layouts.append({"episodes": [len(self.laps)], "xy": o.xy[self.i].tolist(),
                                 "yaw": o.yaw[self.i].tolist(), "lane": o.lane[self.i].tolist()})

    def finish(self) -> None:
        self.trace.set_last("done", True)
        if self.layouts:  # the simtrace's episode numbers (one per lap) this layout stood for
            first = self.layouts[-1]["episodes"][0]
            self.layouts[-1]["episodes"] = list(range(first, max(len(self.laps), first + 1)))

    def _step(self) -> bool:
        """One environment step; True when the episode is over."""
        if self.hold is not None:
            self.sim.pause_step(self.car)
            return self.held()
        obs, actions = self.act()
        codes, rewards = self.world.step(actions, self.active)
        return self.after(codes, rewards, obs, actions)

    def act(self) -> tuple:
        """The car's observation and the policy's action for it."""
        obs = self.world.observe()
        if self.sim.num_cars > 1:
            obs = observation_row(obs, self.i)
        return obs, self.policy(obs)

    def after(self, codes, rewards, obs, actions) -> bool:
        """The car's row of a step it drove; True when its episode is over."""
        code = int(codes[self.i])
        status = STATUS_NAMES[code]
        before = self.ep.prev
        self._add_row(self.sim.trace_columns(self.car), actions, float(rewards[self.i]), status, obs)
        if code == Status.LAP_COMPLETE:
            return self._lap_complete()
        if status in INCIDENTS:
            return self._incident(status, before)
        if self.sim.truncated[self.i]:
            self._close_lap("time_up")
            return True
        return False

    # ---- laps ---------------------------------------------------------------------------------
    def _lap_complete(self) -> bool:
        self._close_lap("lap_complete")
        ep = self.ep
        ep.laps_left -= 1
        if ep.laps_left == 0:
            return True
        self.trace.set_last("episode_status", "in_progress")
        self._restart_progress()
        ep.lap_start = self.sim.time
        ep.first_row = len(self.trace)
        ep.counts = dict.fromkeys(INCIDENTS, 0)
        return False

    def _restart_progress(self) -> None:
        """Continuous laps: progress counts from the start line again (simapp sets prev_progress to 0
        after a 100 %), and the reset rules start afresh."""
        self.sim.restart_lap(self.i)
        self.ep.prev = (float(self.sim.state.progress[self.i]), *self.ep.prev[1:])

    def _close_lap(self, status: str) -> None:
        ep = self.ep
        progress = 100.0 if status == "lap_complete" else float(self.trace.last("progress"))
        lap = Lap(len(self.laps) + 1, status, ep.lap_start, self.sim.time, progress, dict(ep.counts),
                  len(self.trace) - ep.first_row)
        self.laps.append(lap)
        if self.on_lap:
            self.on_lap(lap)

    # ---- incidents ----------------------------------------------------------------------------
    def _incident(self, status: str, before: tuple) -> bool:
        ep = self.ep
        ep.counts[status] += 1
        if ep.resets >= self.rules.max_resets:
            self._close_lap(status)
            return True
        ep.resets += 1
        penalty = self.rules.penalty(status)
        self.trace.set_last("pause_duration", penalty)
        objects = self.sim.objects
        if status == "crashed" and objects is not None and (objects.bots or objects.racers):
            self._stop_in_place()  # simapp: after hitting a bot car (or another racer) the car waits where it is
        elif status == "crashed" and objects is not None:
            ep.obstacle_crashes += 1
            self.trace.set_last("obstacle_crash_counter", ep.obstacle_crashes)
            self._put_behind_obstacle(before)
        else:
            self._put_back(before)
        self._hold(penalty)
        return False

    def _put_back(self, before: tuple) -> None:
        """Stop the car on the nearer lane at the previous step's progress, aligned with the lane."""
        sim = self.sim
        progress, mx, my, heading = before
        length = self.track.length
        s = (sim.state.start[self.i] + progress / 100.0) * length
        s = s % length if self.track.closed else min(max(s, 0.0), length)
        yaw = math.radians(heading)
        base = (mx - MODEL_POINT_AHEAD_M * math.cos(yaw), my - MODEL_POINT_AHEAD_M * math.sin(yaw))
        x, y, new_yaw = self.lanes.reset_pose(s, base)
        # measure the new pose against the progress the car is put back at, not where it left the road
        sim.relocate(self.i, x, y, new_yaw, progress=progress)

    def _stop_in_place(self) -> None:
        car, i = self.sim.state, self.i
        self.sim.relocate(i, float(car.x[i]), float(car.y[i]), float(car.yaw[i]))

    def _put_behind_obstacle(self, before: tuple) -> None:
        """After hitting a box: 1 m behind it in the other lane (simapp's obstacle reset), progress moved back
        by the centre-line distance between the two points. With the mercy reset, the `max_resets_after_crash`-th
        crash in a row into the same box puts the car `reset_ahead_dist` ahead of it instead (progress moved on)."""
        sim, ep, rules = self.sim, self.ep, self.rules
        progress, mx, my, _ = before
        length = self.track.length
        box = sim.objects.nearest(self.i, mx, my)
        ep.same_box_crashes = ep.same_box_crashes + 1 if box == ep.last_box else 1
        ep.last_box = box
        along = -RESET_BEHIND_DIST_M
        if rules.enable_mercy_reset and ep.same_box_crashes >= rules.max_resets_after_crash:
            along = rules.reset_ahead_dist
            ep.last_box, ep.same_box_crashes = -1, 0
        s_before = (sim.state.start[self.i] + progress / 100.0) * length
        x, y, yaw, s = sim.objects.reset_behind(self.i, bool(sim.state.reversed[self.i]), mx, my, along)
        moved = s - s_before
        if self.track.closed:  # the shorter way round: behind or (mercy) ahead
            moved = (moved + 0.5 * length) % length - 0.5 * length
        sim.relocate(self.i, x, y, yaw, progress=progress + 100.0 * moved / length)

    def _hold(self, penalty: float) -> None:
        """The car stands still for the penalty (pause rows, one per step); the sim clock runs on."""
        obs, actions = self.act()  # held still, the car sees the same picture each step
        self.hold = (pause_steps(penalty, self.sim.dt), penalty, 0, obs, actions)

    def held(self) -> bool:
        """The pause row of a step in which the car was held (its step counter counted it, as simapp counts
        pause steps); the row shows where it was put back (its current pose), not the incident's."""
        left, penalty, k, obs, actions = self.hold
        k += 1
        self._add_row(self.sim.trace_columns(self.car, judged=False), actions, 0.0, "pause", obs,
                      pause=max(penalty - k * self.sim.dt, 0.0))
        self.hold = (left - 1, penalty, k, obs, actions) if left > 1 else None
        return False

    # ---- rows ---------------------------------------------------------------------------------
    def _add_row(self, cols: dict, actions, reward: float, status: str, obs, pause: float = 0.0) -> None:
        """One simtrace row from the simulator's `trace_columns` of the car and what the driver knows."""
        sim = self.sim
        steer, speed = self.world.commands(actions)
        if status == "prepare":
            steer, speed = np.zeros(1), np.zeros(1)
        action = int(actions[0]) if self.discrete else [float(steer[0]), float(speed[0])]
        car, i = sim.state, self.i
        row = {c: v[0].item() for c, v in cols.items()}
        row.update({
            "episode": len(self.laps), "steer": float(steer[0]), "throttle": float(speed[0]), "action": action,
            "reward": reward, "done": False, "track_len": self.track.length, "episode_status": status,
            "pause_duration": pause, "obstacle_crash_counter": self.ep.obstacle_crashes, "wall_clock": time.time(),
            "base_x": float(car.x[i]), "base_y": float(car.y[i]), "base_yaw": float(car.yaw[i]),
            "speed": float(car.speed[i]), "lap_clock": sim.time - self.ep.lap_start,
        })
        self.trace.add(row)
        self.ep.prev = (row["progress"], row["X"], row["Y"], row["yaw"])
        if self.frames is not None:
            self.frames.append(self.image_of(obs) if self.image_of else None)
        if self.object_poses is not None:
            self.object_poses.append(np.column_stack([sim.objects.xy[i], sim.objects.yaw[i]]))

    def objects_record(self) -> dict | None:
        """The objects' poses per row with their size, for a video (`EvalRun.objects`)."""
        if self.object_poses is None:
            return None
        o = self.sim.objects
        return {"pose": self.object_poses, "size": tuple(float(v) for v in o.box_size_m),
                "cars": bool(getattr(o, "bots", False) or getattr(o, "racers", False))}

    def layouts_record(self) -> dict | None:
        """The layouts of the episodes driven (`EvalRun.layouts`): {"kind": "box" | "bot", "size": [length,
        width] m, "layouts": [{"episodes": simtrace episode numbers, "xy", "yaw", "lane"}]}; None without boxes
        or bot cars."""
        if not self.layouts:
            return None
        o = self.sim.objects
        return {"kind": "bot" if o.bots else "box", "size": [float(v) for v in o.box_size_m],
                "layouts": self.layouts}


def run_evaluation(world, policy: Callable, rules: RaceRules | None = None, *, keep_frames: bool = False,
                   image_of: Callable | None = None, on_lap: Callable[[Lap], None] | None = None) -> EvalRun:
    """Drive car 0 of `world` (a one-car `World`) under `rules` with `policy(obs) -> actions` (batch of 1).

    `keep_frames` keeps `image_of(obs)` (e.g. the camera picture) for every row, for a video;
    `on_lap(lap)` is called as each lap ends.
    """
    if world.sim.num_cars != 1:
        raise ValueError("run_evaluation drives a one-car world")
    rules = rules or RaceRules()
    t0 = time.perf_counter()
    driver = _Driver(world, policy, rules, keep_frames, image_of, on_lap)
    driver.run()
    trace, extra = driver.trace.arrays(continuous_actions=not driver.discrete)
    return EvalRun(driver.laps, trace, extra, driver.frames, time.perf_counter() - t0, world.sim.dt,
                   objects=driver.objects_record(), layouts=driver.layouts_record())


# ---- head to model ------------------------------------------------------------------------------------------
def grid_poses(track, num_cars: int) -> list[tuple[float, float, float]]:
    """Start poses (x, y, yaw rad) of a head-to-model race: on the start line, car 0 on the inner lane, car 1 on
    the outer one, each heading along its lane."""
    lanes = Lanes(track)
    c = track.point_at(0.0)
    out = []
    for k in range(num_cars):
        foot, yaw = project_on_polyline(lanes.lines[k % 2], c)
        out.append((float(foot[0]), float(foot[1]), yaw))
    return out


def _park(sim, car: int) -> None:
    """A car whose race is over leaves the track (AWS parks it), so the other car drives on alone."""
    lo = np.minimum(sim.track.outer.min(axis=0), sim.track.inner.min(axis=0))
    sim.relocate(car, float(lo[0]) - 10.0 - 2.0 * car, float(lo[1]) - 10.0, 0.0)


def run_head_to_model(worlds, policies, rules: RaceRules | None = None, *, keep_frames: bool = False,
                      image_of: Callable | None = None, on_lap: Callable | None = None) -> list[EvalRun]:
    """Two models racing in one world: `worlds[k]` (sharing one simulator whose race is head_to_model) drives car
    k with `policies[k]`; each car sees the other (its object: the lidar, `objects_*`), crashes into it by the
    crash rule, and is judged, held and put back under `rules` on its own while the other drives on. Both
    start on the start line, car 0 on the inner lane and car 1 on the outer one; a car whose race is over is
    parked off the track. `on_lap(k, lap)` is called as car k ends a lap. Returns each car's `EvalRun`."""
    rules = rules or RaceRules()
    sim = worlds[0].sim
    n = len(worlds)
    if sim.num_cars != n or any(w.sim is not sim for w in worlds) or sim.objects is None or not sim.objects.racers:
        raise ValueError("run_head_to_model drives worlds that share one head_to_model simulator, a car each")
    t0 = time.perf_counter()
    drivers = [_Driver(w, p, rules, keep_frames, image_of, (lambda lap, k=k: on_lap(k, lap)) if on_lap else None,
                       car=k) for k, (w, p) in enumerate(zip(worlds, policies, strict=True))]
    track = drivers[0].track
    episodes = [rules.trials] if rules.continuous and track.closed else [1] * rules.trials
    for laps in episodes:
        sim.reset(start_ndist=0.0, reverse=rules.reverse)
        for k, (x, y, yaw) in enumerate(grid_poses(track, n)):
            sim.set_pose(k, x, y, yaw, start_ndist=0.0, reverse=rules.reverse)
        for d in drivers:
            d.begin(laps)
        _race_episode(sim, worlds, drivers)
        for d in drivers:
            d.finish()
    wall = time.perf_counter() - t0
    runs = []
    for d in drivers:
        trace, extra = d.trace.arrays(continuous_actions=not d.discrete)
        runs.append(EvalRun(d.laps, trace, extra, d.frames, wall, sim.dt, objects=d.objects_record()))
    return runs


def _race_episode(sim, worlds, drivers) -> None:
    """Step every car still racing together until each one's episode is over."""
    n = len(drivers)
    done = [False] * n
    while not all(done):
        driving = [k for k in range(n) if not done[k] and drivers[k].hold is None]
        held = [k for k in range(n) if not done[k] and drivers[k].hold is not None]
        steer, speed = np.zeros(n), np.zeros(n)
        acts = {}
        for k in driving:
            obs, actions = drivers[k].act()
            acts[k] = (obs, actions)
            st, sp = worlds[k].commands(actions)
            steer[k], speed[k] = st[0], sp[0]
        active = np.zeros(n, dtype=bool)
        active[driving] = True
        codes = sim.step(steer, speed, active).copy()
        if held:
            sim.count_held(np.array(held))
        for k in held:
            drivers[k].held()
        for k in driving:
            rewards = worlds[k].rewards(codes, drivers[k].active)
            done[k] = drivers[k].after(codes, rewards, *acts[k])
            if done[k]:
                _park(sim, k)
