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
  reset rules there. (On an open track every trial is its own episode.)
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
from racerlab.evaluate.rules import INCIDENTS, Lanes, RaceRules, pause_steps
from racerlab.logs import SIMTRACE_COLUMNS
from racerlab.sim import STATUS_NAMES, Status
from racerlab.spec import MODEL_POINT_AHEAD_M, STEP_S

ACTIVE = np.ones(1, dtype=bool)
CAR = np.zeros(1, dtype=np.int64)  # the one car, as an index array
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


class _Driver:
    def __init__(self, world, policy: Callable, rules: RaceRules, keep_frames: bool,
                 image_of: Callable | None, on_lap: Callable | None):
        self.world = world
        self.sim = world.sim
        self.policy = policy
        self.rules = rules
        self.track = self.sim.track_reversed if rules.reverse else self.sim.track
        self.lanes = Lanes(self.track)
        self.trace = _Trace()
        self.laps: list[Lap] = []
        self.frames = [] if keep_frames else None
        self.image_of = image_of
        self.on_lap = on_lap
        self.discrete = world.discrete
        self.ep: _Episode | None = None

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
        self.ep = _Episode(laps_left=laps, lap_start=sim.time, first_row=len(self.trace))
        while not self._step():
            pass
        self.trace.set_last("done", True)

    def _step(self) -> bool:
        """One environment step; True when the episode is over."""
        obs = self.world.observe()
        actions = self.policy(obs)
        codes, rewards = self.world.step(actions, ACTIVE)
        code = int(codes[0])
        status = STATUS_NAMES[code]
        before = self.ep.prev
        self._add_row(self.sim.trace_columns(CAR), actions, float(rewards[0]), status, obs)
        if code == Status.LAP_COMPLETE:
            return self._lap_complete()
        if status in INCIDENTS:
            return self._incident(status, before)
        if self.sim.truncated[0]:
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
        self._restart_progress()
        ep.lap_start = self.sim.time
        ep.first_row = len(self.trace)
        ep.counts = dict.fromkeys(INCIDENTS, 0)
        return False

    def _restart_progress(self) -> None:
        """Continuous laps: progress counts from the start line again (simapp sets prev_progress to 0
        after a 100 %), and the reset rules start afresh."""
        self.sim.restart_lap(0)
        self.ep.prev = (float(self.sim.state.progress[0]), *self.ep.prev[1:])

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
        if status == "crashed" and self.sim.objects is not None and self.sim.objects.bots:
            self._stop_in_place()  # simapp: after hitting a bot car the car waits where it is
        elif status == "crashed" and self.sim.objects is not None:
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
        s = (sim.state.start[0] + progress / 100.0) * length
        s = s % length if self.track.closed else min(max(s, 0.0), length)
        yaw = math.radians(heading)
        base = (mx - MODEL_POINT_AHEAD_M * math.cos(yaw), my - MODEL_POINT_AHEAD_M * math.sin(yaw))
        x, y, new_yaw = self.lanes.reset_pose(s, base)
        # measure the new pose against the progress the car is put back at, not where it left the road
        sim.relocate(0, x, y, new_yaw, progress=progress)

    def _stop_in_place(self) -> None:
        car = self.sim.state
        self.sim.relocate(0, float(car.x[0]), float(car.y[0]), float(car.yaw[0]))

    def _put_behind_obstacle(self, before: tuple) -> None:
        """After hitting a box: 1 m behind it in the other lane (simapp's obstacle reset), progress moved back
        by the centre-line distance between the two points."""
        sim = self.sim
        progress, mx, my, _ = before
        length = self.track.length
        s_before = (sim.state.start[0] + progress / 100.0) * length
        x, y, yaw, s = sim.objects.reset_behind(0, bool(sim.state.reversed[0]), mx, my)
        back = (s_before - s) % length if self.track.closed else s_before - s
        sim.relocate(0, x, y, yaw, progress=progress - 100.0 * back / length)

    def _hold(self, penalty: float) -> None:
        """The pause rows: the car stands still for the penalty; the sim clock runs on."""
        sim = self.sim
        obs = self.world.observe()
        actions = self.policy(obs)  # held still, the car sees the same picture each step
        for k in range(1, pause_steps(penalty, sim.dt) + 1):
            sim.pause_step(CAR)  # simapp counts pause steps
            # the held car's row shows where it was put back (its current pose), not the incident's
            self._add_row(sim.trace_columns(CAR, judged=False), actions, 0.0, "pause", obs,
                          pause=max(penalty - k * sim.dt, 0.0))

    # ---- rows ---------------------------------------------------------------------------------
    def _add_row(self, cols: dict, actions, reward: float, status: str, obs, pause: float = 0.0) -> None:
        """One simtrace row from the simulator's `trace_columns` of the car and what the driver knows."""
        sim = self.sim
        steer, speed = self.world.commands(actions)
        if status == "prepare":
            steer, speed = np.zeros(1), np.zeros(1)
        action = int(actions[0]) if self.discrete else [float(steer[0]), float(speed[0])]
        car = sim.state
        row = {c: v[0].item() for c, v in cols.items()}
        row.update({
            "episode": len(self.laps), "steer": float(steer[0]), "throttle": float(speed[0]), "action": action,
            "reward": reward, "done": False, "track_len": self.track.length, "episode_status": status,
            "pause_duration": pause, "obstacle_crash_counter": self.ep.obstacle_crashes, "wall_clock": time.time(),
            "base_x": float(car.x[0]), "base_y": float(car.y[0]), "base_yaw": float(car.yaw[0]),
            "speed": float(car.speed[0]), "lap_clock": sim.time - self.ep.lap_start,
        })
        self.trace.add(row)
        self.ep.prev = (row["progress"], row["X"], row["Y"], row["yaw"])
        if self.frames is not None:
            self.frames.append(self.image_of(obs) if self.image_of else None)


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
    return EvalRun(driver.laps, trace, extra, driver.frames, time.perf_counter() - t0, world.sim.dt)
