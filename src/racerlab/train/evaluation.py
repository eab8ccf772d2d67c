"""Greedy evaluation episodes inside training (AWS's MIN_EVAL_TRIALS) and the best-model metric."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from racerlab.agent.common import take
from racerlab.sim import STATUS_NAMES

UNFINISHED_LAP_MS = 999_999  # AWS counts an unfinished lap as this when ranking by lap time


@dataclass
class EvalEpisode:
    start_ndist: float
    status: str
    steps: int
    progress: float
    reward: float
    lap_time: float  # s, NaN unless the lap was completed
    start_time: float
    end_time: float


def run_greedy_episodes(agent, world, starts) -> list[EvalEpisode]:
    """One greedy episode per car of `world`, car i starting at fraction `starts[i]` of the lap."""
    sim = world.sim
    n = sim.num_cars
    starts = np.asarray(starts, dtype=np.float64)
    sim.reset(start_ndist=starts, reverse=world.sim.start_rules.reverse)
    active = np.ones(n, dtype=bool)
    reward = np.zeros(n)
    results: list[EvalEpisode | None] = [None] * n
    t0 = sim.time
    while active.any():
        idx = np.flatnonzero(active)
        codes, r = world.step(agent.policy(take(world.observe(), idx)), active)
        reward += r
        done = active & (sim.terminated_mask(codes) | sim.truncated)
        for i in np.flatnonzero(done).tolist():
            status = STATUS_NAMES[int(codes[i])] if not sim.truncated[i] else "time_up"
            steps = int(sim.steps[i])
            results[i] = EvalEpisode(float(starts[i]), status, steps, float(sim.judged.progress[i]), float(reward[i]),
                                     steps * sim.dt if status == "lap_complete" else math.nan, t0, sim.time)
        active &= ~done
    return results


def eval_metric(episodes: list[EvalEpisode], metric: str) -> float:
    """Mean progress or reward (higher is better) or mean lap time in ms (lower is better)."""
    if not episodes:
        return float("nan")
    if metric == "progress":
        return float(np.mean([e.progress for e in episodes]))
    if metric == "reward":
        return float(np.mean([e.reward for e in episodes]))
    return float(np.mean([e.lap_time * 1000 if e.status == "lap_complete" else UNFINISHED_LAP_MS
                          for e in episodes]))


def laptime_tie_ms(episodes: list[EvalEpisode], dt: float) -> float:
    """How much slower than the fastest mean evaluation lap so far a checkpoint's mean lap may be and still tie
    with it, in ms: one step (`dt`) in one of the evaluation's laps. Laps come in whole steps, so the mean of n
    laps moves in quanta of dt / n, and a plateaued policy's evaluations wander by a quantum or two from
    iteration to iteration (the quickstart's 932 iterations: 5.307-5.373 s around a 5.20 s best lap). Counting a
    one-quantum difference as a tie keeps the newest of the equally fast checkpoints, not the one that drew the
    luckiest evaluation."""
    return 1000.0 * dt / max(len(episodes), 1)


def is_better(metric: str, value: float, best: float | None, tie: float = 0.0) -> bool:
    """AWS keeps the newer checkpoint on ties (>= / <=); for "laptime" `best` is the fastest mean lap so far and
    a value up to `tie` ms slower ties with it (`laptime_tie_ms`)."""
    if best is None or math.isnan(best):
        return not math.isnan(value)
    return value <= best + tie if metric == "laptime" else value >= best


def pick_best(metric: str, value: float, best: float | None, floor: float | None = None,
              tie: float = 0.0) -> tuple[bool, float | None]:
    """Whether the checkpoint whose evaluation gave `value` becomes the best one (its predecessor's value: `best`),
    and the fastest mean lap so far after it (`floor`; "laptime" only, None for the others). For "laptime" the
    newest checkpoint within `tie` ms of the fastest mean lap so far is kept, so equally fast checkpoints do not
    hand the pick to the luckiest early evaluation; the others keep AWS's rule."""
    if metric != "laptime":
        return is_better(metric, value, best), None
    floor = best if floor is None else floor
    keep = is_better(metric, value, floor, tie)
    if not math.isnan(value) and (floor is None or math.isnan(floor) or value < floor):
        floor = value
    return keep, floor
