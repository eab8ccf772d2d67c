"""Collecting whole episodes from many cars at once, on one or several tracks.

A `racerlab.sim.World` is one track's simulator with its observation and reward; the `Collector` spreads
the cars over the worlds, asks the agent for all cars' actions in one batch per step, and records
every step as columns (no per-car Python in the step loop apart from the user's reward
function). An iteration ends when its episodes are done; like AWS's trainer it keeps whole
episodes only, in order of completion, while their steps fit under `max_steps` (facts §2).

For learning, an episode that ends because its lap is complete counts as *truncated*, like one cut by
the step cap: the car could drive on, so the agent bootstraps from the value of the observation after
the finish (`Rollout.final_obs`), where AWS bootstraps 0. No observation says how far the finish is
(an episode's finish is wherever it started), so a value net cannot foresee a 0 there; with it, every
step shortly before the finish looked worse than expected, arriving sooner most of all, and lap times
stalled (issue 17). Crashes, going off track and reversing stay terminations (bootstrap 0), as in AWS.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from racerlab.agent.common import take
from racerlab.sim import STATUS_NAMES, TRACE_COLUMNS, Status, World

# statuses after which the car could have driven on: the learner bootstraps from V(final observation)
CONTINUING = ("time_up", "lap_complete")


def concat_obs(parts):
    if isinstance(parts[0], dict):
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return np.concatenate(parts)


@dataclass
class Episode:
    uid: int
    world: int
    car: int
    steps: int = 0
    reward: float = 0.0
    status: str = "in_progress"
    progress: float = 0.0
    start_time: float = 0.0
    end_time: float = 0.0
    lap_time: float = float("nan")


@dataclass
class Rollout:
    """One iteration's kept episodes as flat arrays, episodes concatenated in completion order."""

    obs: object  # [N, ...] or dict; learning steps only (prepare steps excluded)
    actions: np.ndarray
    record: dict  # what the agent's `explore` asked to keep per step (PPO: log_probs, values), [N] each
    rewards: np.ndarray
    terminated: np.ndarray  # [N] last step of an episode that ended for good (crash, off track, ...)
    truncated: np.ndarray  # [N] last step of an episode with a CONTINUING status (step cap, lap complete)
    episodes: list[Episode]
    trace: dict  # simtrace columns of every step of the kept episodes (prepare steps included)
    env_steps: int  # all car-steps simulated, kept or not
    seconds: float
    cut: bool = False  # collection stopped at the time limit; running episodes were dropped
    final_obs: object = None  # set after construction: the observation after each truncated episode


class Collector:
    """Runs whole training episodes for an agent over one or more worlds."""

    def __init__(self, worlds: list[World]):
        self.worlds = worlds
        self.offsets = np.cumsum([0] + [w.sim.num_cars for w in worlds])
        self.num_cars = int(self.offsets[-1])
        self.next_uid = 0

    def collect(self, agent, target_episodes: int, max_steps: int, first_episode_number: int = 0, *,
                deadline: float | None = None, tick=None, tick_s: float = 10.0) -> Rollout:
        """Whole episodes driven with `agent.explore(obs) -> (actions, record)` until `target_episodes` have
        ended or their kept steps reach `max_steps`. At `deadline` (a `time.perf_counter()` value) collection
        stops: the episodes still running are dropped, as AWS drops those past its step cap, and the rollout
        holds the complete ones (`cut` is set). `tick(episodes_done, target, env_steps, seconds)` is called at
        least every `tick_s` seconds while collecting."""
        t0 = last = time.perf_counter()
        state = _IterationState(self, target_episodes, max_steps)
        for w in self.worlds:
            w.sim.reset()
        state.start_all()
        cut = False
        while state.active.any():
            self._step(agent, state)
            now = time.perf_counter()
            if deadline is not None and now >= deadline:
                state.active[:] = False
                cut = True
            elif tick is not None and now - last >= tick_s:
                last = now
                tick(len(state.completed), state.target, state.env_steps, now - t0)
        ro = state.finish(first_episode_number, time.perf_counter() - t0)
        ro.cut = cut
        return ro

    def _observe(self, mask):
        """Observations of the cars in `mask` (global car indices), rendered only for them."""
        parts = []
        for k, w in enumerate(self.worlds):
            lo, hi = self.offsets[k], self.offsets[k + 1]
            parts.append(w.observe(np.flatnonzero(mask[lo:hi])))
        return take(concat_obs(parts), np.flatnonzero(mask))

    def _step(self, agent, state):
        idx = np.flatnonzero(state.active)
        obs = self._observe(state.active)
        actions, record = agent.explore(obs)
        full_actions = np.zeros((self.num_cars, *actions.shape[1:]), dtype=actions.dtype)
        full_actions[idx] = actions
        codes = np.empty(self.num_cars, dtype=np.int64)
        rewards = np.zeros(self.num_cars)
        for k, w in enumerate(self.worlds):
            lo, hi = self.offsets[k], self.offsets[k + 1]
            on = state.active[lo:hi]
            c, r = w.step(full_actions[lo:hi][on], on)
            codes[lo:hi] = c
            rewards[lo:hi] = r
        state.record(idx, obs, actions, record, codes, rewards)
        done = np.zeros(self.num_cars, dtype=bool)
        trunc = np.zeros(self.num_cars, dtype=bool)
        for k, w in enumerate(self.worlds):
            lo, hi = self.offsets[k], self.offsets[k + 1]
            done[lo:hi] = w.sim.terminated_mask(codes[lo:hi]) | w.sim.truncated
            trunc[lo:hi] = w.sim.truncated
        done &= state.active
        if done.any():
            goes_on = done & (trunc | (codes == Status.LAP_COMPLETE))  # the CONTINUING statuses
            final_obs = self._observe(goes_on) if goes_on.any() else None
            state.end_episodes(np.flatnonzero(done), trunc, goes_on, codes, final_obs)


class _IterationState:
    """Bookkeeping of one collection: which car runs which episode, and the recorded columns."""

    def __init__(self, col: Collector, target: int, max_steps: int):
        self.col = col
        self.target = target
        self.max_steps = max_steps
        n = col.num_cars
        self.active = np.zeros(n, dtype=bool)
        self.uid = np.full(n, -1, dtype=np.int64)
        self.started = 0
        self.kept_steps = 0
        self.episodes: dict[int, Episode] = {}
        self.completed: list[int] = []
        self.final_obs: dict[int, object] = {}
        self.blocks: list[dict] = []
        self.env_steps = 0

    def world_of(self, car: int) -> tuple[int, int]:
        k = int(np.searchsorted(self.col.offsets, car, side="right") - 1)
        return k, car - int(self.col.offsets[k])

    def start_all(self):
        cars = np.arange(self.col.num_cars)[: max(self.target, 0)]
        self._start(cars)

    def _start(self, cars):
        for car in np.asarray(cars).tolist():
            k, i = self.world_of(car)
            sim = self.col.worlds[k].sim
            uid = self.col.next_uid
            self.col.next_uid += 1
            self.uid[car] = uid
            self.active[car] = True
            self.episodes[uid] = Episode(uid, k, i, start_time=sim.time)
            self.started += 1

    def record(self, idx, obs, actions, record, codes, rewards):
        self.env_steps += idx.size
        block = {"car": idx, "uid": self.uid[idx], "obs": obs, "actions": actions, "record": record,
                 "rewards": rewards[idx], "codes": codes[idx]}
        block.update(self._trace_columns(idx))
        self.blocks.append(block)

    def _trace_columns(self, idx):
        col = self.col
        parts = []
        for k, w in enumerate(col.worlds):
            lo, hi = col.offsets[k], col.offsets[k + 1]
            parts.append(w.sim.trace_columns(idx[(idx >= lo) & (idx < hi)] - lo))
        out = {c: np.concatenate([p[c] for p in parts]) for c in TRACE_COLUMNS}
        out["wall_clock"] = np.full(idx.size, time.time())
        return out

    def end_episodes(self, cars, trunc, goes_on, codes, final_obs):
        j = 0
        restart = []
        for car in cars.tolist():
            uid = int(self.uid[car])
            ep = self.episodes[uid]
            k, i = self.world_of(car)
            sim = self.col.worlds[k].sim
            ep.steps = int(sim.steps[i])
            ep.status = STATUS_NAMES[int(codes[car])] if not trunc[car] else "time_up"
            ep.progress = float(sim.judged.progress[i])
            ep.end_time = sim.time
            if ep.status == "lap_complete":
                ep.lap_time = ep.steps * sim.dt
            if goes_on[car]:
                self.final_obs[uid] = take(final_obs, j)
                j += 1
            self.active[car] = False
            if self.kept_steps + ep.steps <= self.max_steps:
                self.kept_steps += ep.steps
                self.completed.append(uid)
            else:
                # AWS drops whole episodes beyond the step cap; nothing more would be kept
                self.target = self.started
            if self.started < self.target:
                restart.append(car)
        if self.kept_steps >= self.max_steps:
            self.target = self.started
            self.active[:] = False
            restart = []
        if restart:
            cars_arr = np.array(restart)
            for k, w in enumerate(self.col.worlds):
                lo, hi = self.col.offsets[k], self.col.offsets[k + 1]
                mask = np.zeros(w.sim.num_cars, dtype=bool)
                sel = cars_arr[(cars_arr >= lo) & (cars_arr < hi)] - lo
                mask[sel] = True
                if mask.any():
                    w.sim.reset(mask)
            self._start(cars_arr)

    def finish(self, first_episode_number: int, seconds: float) -> Rollout:
        cols = _concat_blocks(self.blocks)
        kept = np.array(self.completed, dtype=np.int64)
        order_of = {uid: n for n, uid in enumerate(self.completed)}
        rank = np.array([order_of.get(int(u), -1) for u in cols["uid"].tolist()]) if cols else np.zeros(0, int)
        keep = rank >= 0
        steps = cols["steps"] if cols else np.zeros(0, int)
        order = np.flatnonzero(keep)[np.lexsort((steps[keep], rank[keep]))] if cols else np.zeros(0, int)
        episodes = [self.episodes[int(u)] for u in kept]
        trace = {k: cols[k][order] for k in (*TRACE_COLUMNS, "rewards", "codes", "actions", "wall_clock")} \
            if cols else {}
        if cols:
            trace["episode"] = first_episode_number + rank[order]
            for n, ep in enumerate(episodes):
                ep.reward = float(trace["rewards"][trace["episode"] == first_episode_number + n].sum())
        learn = order[cols["codes"][order] != Status.PREPARE] if cols else order
        return self._learning_arrays(cols, learn, episodes, trace, seconds)

    def _learning_arrays(self, cols, learn, episodes, trace, seconds) -> Rollout:
        if not cols or learn.size == 0:
            z = np.zeros(0, np.float32)
            return Rollout(None, np.zeros(0), {}, z, np.zeros(0, bool), np.zeros(0, bool), episodes, trace,
                           self.env_steps, seconds)
        uid = cols["uid"][learn]
        ended = np.append(uid[1:] != uid[:-1], True)
        status = {ep.uid: ep.status for ep in episodes}
        truncated = ended & np.array([status[int(u)] in CONTINUING for u in uid.tolist()])
        terminated = ended & ~truncated
        end_uids = uid[ended].tolist()
        cut = [u for u in end_uids if u in self.final_obs]
        final = concat_obs([_expand(self.final_obs[u]) for u in cut]) if cut else None
        record = {k: v[learn] for k, v in cols["record"].items()}
        ro = Rollout(take(cols["obs"], learn), cols["actions"][learn], record,
                     cols["rewards"][learn].astype(np.float32), terminated, truncated, episodes, trace,
                     self.env_steps, seconds)
        ro.final_obs = final  # observations after each truncated episode's last step, in order
        return ro


def _expand(obs):
    if isinstance(obs, dict):
        return {k: v[None] for k, v in obs.items()}
    return obs[None]


def _concat_blocks(blocks: list[dict]) -> dict:
    if not blocks:
        return {}
    out = {}
    for key in blocks[0]:
        if isinstance(blocks[0][key], dict):
            out[key] = {k: np.concatenate([b[key][k] for b in blocks]) for k in blocks[0][key]}
        else:
            out[key] = np.concatenate([b[key] for b in blocks])
    return out
