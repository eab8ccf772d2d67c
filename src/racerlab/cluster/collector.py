"""Collection over Ray actors: the learner broadcasts weights, N workers return rollouts as arrays.

One iteration is DRfC's synchronous loop: the learner puts the weights in Ray's object store once,
each worker drives its share of the iteration's episodes (episode k goes to worker k mod N, as
DRfC's trainer asks for them), and the driver joins the rollouts in worker order. A worker that
dies mid-iteration costs its episodes only: the iteration completes with the others, the run
says so, and a fresh worker takes the dead one's place for the next iteration.
"""

from __future__ import annotations

import math
import os
import re
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from racerlab.cluster.worker import RolloutWorker, broadcast_state
from racerlab.errors import RacerlabError
from racerlab.train.rollout import Rollout, concat_obs

RAY_MIN = (2, 52)  # the first Ray with token authentication
WORKER_START_S = 600.0  # workers build their worlds (and compile) before they answer
WORKER_TIMEOUT_S = 1800.0  # one iteration's collection on a worker, at most
STRAGGLER_FACTOR = 3.0  # once a worker has answered, the others get this many times its time...
STRAGGLER_MIN_S = 60.0  # ...plus this
READY_GET_S = 60.0  # fetching a finished call's result (its arrays from the object store), at most


def split_episodes(target: int, workers: int) -> list[int]:
    """Episodes per worker when episode k is served by worker k mod `workers` (DRfC)."""
    return [len(range(k, target, workers)) for k in range(workers)]


def connect(address: str | None = None, num_cpus: int | None = None):
    """`ray.init` once per process: an existing cluster at `address` (or RAY_ADDRESS), else a local one.

    A local cluster serves on 127.0.0.1 only (`loopback_only`) and is started with Ray's token authentication
    (RAY_AUTH_MODE=token, Ray >= 2.52), unless RAY_AUTH_MODE says otherwise. A Ray this process is already
    connected to is used as it is."""
    ray = import_ray(address)
    if _version(ray.__version__) < RAY_MIN:
        raise RacerlabError(f"ray {ray.__version__} is installed; racerlab needs ray >= "
                            f"{'.'.join(map(str, RAY_MIN))} (token authentication): pip install -U 'racerlab[cluster]'")
    if not ray.is_initialized():
        kwargs = {"include_dashboard": False, "log_to_driver": False, "configure_logging": False}
        if address:
            ray.init(address=address, **kwargs)
        else:
            ray.init(num_cpus=num_cpus, **kwargs)
    return ray


def import_ray(address: str | None = None):
    """Ray, imported after its authentication mode and addresses are chosen: Ray reads RAY_AUTH_MODE once, when it is
    imported, and hands the environment to the node processes it starts, so a mode set after the import leaves the
    driver without a token while the cluster asks for one. A local cluster (no `address`, no RAY_ADDRESS) serves on
    loopback and gets token authentication unless RAY_AUTH_MODE says otherwise; a Ray imported earlier in the process
    re-reads it. A Ray already connected is left alone: re-reading its configuration under a connection it made with
    another mode takes the connection down (the driver then dies at its next call)."""
    ray = sys.modules.get("ray")
    if ray is not None and getattr(ray, "is_initialized", lambda: False)():
        return ray
    if not (address or os.environ.get("RAY_ADDRESS")):
        loopback_only()
        if "RAY_AUTH_MODE" not in os.environ:
            os.environ["RAY_AUTH_MODE"] = "token"
            if ray is not None:
                _reread_ray_config(ray)
    import ray

    return ray


def loopback_only() -> None:
    """Make the local cluster this process starts (or joins on this machine) serve on 127.0.0.1 only. Ray turns a node
    address of 127.0.0.1 into the machine's network address, and its GCS and raylets then listen on every interface,
    unless clusters of several machines are off: RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0 says that on every system (the
    default on Windows and macOS). Ray reads it when it is imported and hands it to the processes it starts; a Ray
    imported earlier gets its constant set too."""
    os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
    constants = sys.modules.get("ray._private.ray_constants")
    if constants is not None:
        constants.ENABLE_RAY_CLUSTER = False


def _reread_ray_config(ray) -> None:
    """What ray.init itself calls when it turns token authentication on, on the Ray that `import ray` gives (never
    another one found by name)."""
    config = getattr(getattr(ray, "_raylet", None), "Config", None)
    if config is not None:  # a Ray too old for token authentication has none: connect() refuses it next
        config.initialize("")


def _version(text: str) -> tuple[int, ...]:
    return tuple(int(p) for p in re.findall(r"\d+", text)[:2]) or (0,)


@dataclass
class WorkerReport:
    """What happened to the workers in one iteration (the run prints the failures)."""

    finished: list[int] = field(default_factory=list)
    failed: dict[int, str] = field(default_factory=dict)
    weights_bytes: int = 0
    rollout_bytes: dict[int, int] = field(default_factory=dict)


class RayCollector:
    """The `Collector` interface (`collect(agent, target, max_steps, first_episode_number)`) over Ray actors."""

    def __init__(self, model_dir, workers: int, overrides: dict, address: str | None = None, note=print):
        if workers < 1:
            raise RacerlabError(f"--workers {workers}: need at least 1 worker; give --workers 2 or more")
        self.ray = connect(address)
        self.model_dir = str(model_dir)
        self.n = workers
        self.overrides = overrides
        self.note = note
        self.actor_class = self.ray.remote(num_cpus=1, max_restarts=0)(RolloutWorker)
        self.worker_timeout_s = WORKER_TIMEOUT_S
        self.actors = [self._spawn(k) for k in range(workers)]
        try:
            self.info = self.ray.get([a.describe.remote() for a in self.actors], timeout=WORKER_START_S)
        except self.ray.exceptions.GetTimeoutError:
            raise RacerlabError(f"{self.model_dir}: the {workers} rollout workers did not start within "
                                f"{WORKER_START_S:g} s; check `ray status` (free CPUs) and start again") from None
        except self.ray.exceptions.RayTaskError as exc:
            raise remote_error(exc, self.model_dir) from None
        self.episodes = [0] * workers  # each worker counts its own episodes from 0, as the simulator does
        self.report = WorkerReport()
        self.starts: list[list[int]] = [[] for _ in range(workers)]

    def _spawn(self, k: int):
        return self.actor_class.remote(self.model_dir, k, self.n, self.overrides)

    def _revive(self, k: int) -> None:
        self.actors[k] = self._spawn(k)
        if self.starts[k]:
            self.actors[k].set_starts.remote(self.starts[k])

    def collect(self, agent, target_episodes: int, max_steps: int, first_episode_number: int = 0, *,
                deadline: float | None = None, tick=None, tick_s: float = 10.0) -> Rollout:
        """`target_episodes` whole episodes, split over the workers, driven with the learner's current weights.
        `deadline` (the driver's `time.perf_counter()` value) reaches each worker as the seconds left; `tick` is
        called at least every `tick_s` seconds while waiting, with the finished workers' episodes and steps."""
        t0 = time.perf_counter()
        weights = broadcast_state(agent)
        ref = self.ray.put(weights)
        report = WorkerReport(weights_bytes=_pickled_bytes(weights))
        counts = split_episodes(target_episodes, self.n)
        calls = {}
        for k, c in enumerate(counts):
            if c:
                steps = max(1, math.ceil(max_steps * c / max(target_episodes, 1)))
                left = None if deadline is None else deadline - time.perf_counter()
                calls[k] = self.actors[k].collect.remote(ref, c, steps, self.episodes[k], left)
        stalled, waited = self._wait(calls, counts, t0, tick, tick_s)
        parts = []
        for k, fut in calls.items():
            if fut in stalled:  # stopped, hung or cut off: given up, replaced by a fresh worker
                report.failed[k] = f"no answer within {waited:.0f} s"
                self.ray.kill(self.actors[k])
                self._revive(k)
                continue
            try:
                ro, starts = self.ray.get(fut, timeout=READY_GET_S)  # _wait saw it finish: the result is there
            except (self.ray.exceptions.RayActorError, self.ray.exceptions.WorkerCrashedError,
                    self.ray.exceptions.GetTimeoutError) as exc:
                report.failed[k] = type(exc).__name__
                self._revive(k)
                continue
            except self.ray.exceptions.RayTaskError as exc:
                raise remote_error(exc, f"{self.model_dir}: worker {k}") from None
            report.finished.append(k)
            report.rollout_bytes[k] = array_bytes(ro)
            self.starts[k] = starts
            parts.append((k, ro, self.episodes[k]))
            self.episodes[k] += len(ro.episodes)
        self.report = report
        if report.failed:
            lost = ", ".join(f"worker {k} ({why})" for k, why in report.failed.items())
            self.note(f"{lost} failed during the iteration: it completes with {len(parts)} of {len(calls)} workers' "
                      "episodes; a fresh worker takes its place next iteration")
        if not parts:
            raise RacerlabError(f"{self.model_dir}: every rollout worker died in this iteration; check `ray status` "
                                "and the workers' logs under the Ray session folder, then resume the training")
        merged = merge_rollouts([ro for _, ro, _ in parts], first_episode_number, time.perf_counter() - t0)
        merged.parts = parts  # (worker, its rollout, its first episode number): the per-worker logs
        merged.cut = any(getattr(ro, "cut", False) for _, ro, _ in parts)
        return merged

    def _wait(self, calls: dict, counts: list[int], t0: float, tick, tick_s: float) -> tuple[set, float]:
        """Wait for every worker's call to finish (or fail), calling `tick` every `tick_s` seconds with the
        episodes of the workers done so far. A worker gets `worker_timeout_s` at most, and once another has
        answered, STRAGGLER_FACTOR times that one's time plus STRAGGLER_MIN_S; returns the calls still
        pending then (a stopped or hung worker) and the seconds waited."""
        pending, first = list(calls.values()), None
        while pending:
            limit = self.worker_timeout_s if first is None else min(self.worker_timeout_s,
                                                                   STRAGGLER_FACTOR * first + STRAGGLER_MIN_S)
            left = limit - (time.perf_counter() - t0)
            if left <= 0:
                return set(pending), time.perf_counter() - t0
            _, pending = self.ray.wait(pending, num_returns=len(pending), timeout=min(tick_s, left))
            if first is None and len(pending) < len(calls):
                first = time.perf_counter() - t0
            if pending and tick is not None:
                waiting = set(pending)
                done = sum(counts[k] for k, fut in calls.items() if fut not in waiting)
                tick(done, sum(counts), None, time.perf_counter() - t0)
        return set(), time.perf_counter() - t0

    def close(self) -> None:
        for a in self.actors:
            self.ray.kill(a)
        self.actors = []


def remote_error(exc, where) -> RacerlabError:
    """One line for an exception raised inside a worker (Ray's own message carries the remote traceback)."""
    cause = getattr(exc, "cause", None) or exc
    if isinstance(cause, RacerlabError) and not isinstance(cause, type(exc)):
        return cause  # racerlab's own message (a reward's error names its file, line and params)
    lines = [ln.strip() for ln in str(cause).splitlines() if ln.strip()]
    return RacerlabError(f"{where}: {type(cause).__name__}: {lines[-1] if lines else ''}; the worker's log under "
                         "the Ray session folder has the traceback")


def merge_rollouts(parts: list[Rollout], first_episode_number: int, seconds: float) -> Rollout:
    """The workers' rollouts as one, episodes in worker order, numbered on from `first_episode_number`."""
    learn = [p for p in parts if p.rewards.size]
    obs = concat_obs([p.obs for p in learn]) if learn else None
    keys = learn[0].record.keys() if learn else ()
    record = {k: np.concatenate([p.record[k] for p in learn]) for k in keys}
    trace, n = {}, first_episode_number
    traced = [p for p in parts if p.trace]
    for p in traced:
        local = p.trace["episode"] - p.trace["episode"].min() if p.trace["episode"].size else p.trace["episode"]
        shifted = dict(p.trace, episode=local + n)
        for key, v in shifted.items():
            trace.setdefault(key, []).append(v)
        n += len(p.episodes)
    trace = {k: np.concatenate(v) for k, v in trace.items()}
    finals = [p.final_obs for p in learn if p.final_obs is not None]

    def cat(name, dtype):
        arrays = [getattr(p, name) for p in learn]
        return np.concatenate(arrays) if arrays else np.zeros(0, dtype)

    ro = Rollout(obs, cat("actions", np.float64), record, cat("rewards", np.float32), cat("terminated", bool),
                 cat("truncated", bool), [e for p in parts for e in p.episodes], trace,
                 sum(p.env_steps for p in parts), seconds)
    ro.final_obs = concat_obs(finals) if finals else None
    return ro


def _pickled_bytes(obj) -> int:
    import pickle

    return len(pickle.dumps(obj, protocol=5))


def array_bytes(obj) -> int:
    """The bytes of every numpy array inside a rollout (what crosses the network, give or take pickling)."""
    if isinstance(obj, np.ndarray):
        return obj.nbytes
    if isinstance(obj, dict):
        return sum(array_bytes(v) for v in obj.values())
    if isinstance(obj, Rollout):
        return sum(array_bytes(getattr(obj, k)) for k in ("obs", "actions", "record", "rewards", "terminated",
                                                           "truncated", "trace", "final_obs"))
    return 0
