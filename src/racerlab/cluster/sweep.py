"""`racerlab sweep SPEC.toml`: several models trained in parallel on Ray, raced under one set of rules.

Plain Ray, not Ray Tune: a sweep here is a short fixed list of model folders (no search algorithm, no
early stopping), each training is an ordinary `racerlab.train.train` run in one Ray task, and the
ranking is `racerlab.evaluate.race` — the race rules every other leaderboard uses. Tune would add a
trial runner, its own results folders and its own checkpoints next to the model folders' own.

SPEC.toml (paths relative to the file)::

    out = "sweep"                 # the folder that gets one model folder per entry and the leaderboard
    track = "lab_technical"       # training and race track
    iterations = 2                # training iterations per model
    cars = 4
    [race]                        # RaceRules fields (trials, continuous, off_track_penalty, ...)
    trials = 3
    [[model]]
    name = "fast-lr"
    action_space = "continuous"   # or "discrete"; also sensor, algorithm, max_speed
    reward = "rewards/centre.py"  # optional reward_function.py
    hyperparameters = { lr = 0.001, num_epochs = 3 }

No wait on the cluster is unbounded: a training that shows no progress in its model folder (its lock, a
checkpoint, a metrics line) for `stall_s` (TRAINING_STALL_S) is given up (a stopped or hung worker) and left out
of the race, as the collector gives up a worker; an error inside a training is its one line, not Ray's traceback.
"""

from __future__ import annotations

import json
import re
import shutil
import time
import tomllib
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from racerlab.cluster.collector import READY_GET_S, WORKER_START_S, WORKER_TIMEOUT_S, connect, remote_error
from racerlab.errors import RacerlabError
from racerlab.evaluate import Leaderboard, RaceRules, race
from racerlab.logs import metrics_jsonl_path
from racerlab.model import ModelFolder, init_model

_INIT_KEYS = ("sensor", "action_space", "algorithm", "max_speed")
# a training shows progress at least once per iteration (a checkpoint, a metrics line); its first iteration builds
# the worlds (the collector's WORKER_START_S) and collects (WORKER_TIMEOUT_S at most)
TRAINING_STALL_S = WORKER_START_S + WORKER_TIMEOUT_S
_MODEL_KEYS = {"name", "reward", "hyperparameters", *_INIT_KEYS}
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")  # a plain folder name inside out: no "..", no "/"


@dataclass
class SweepBoard:
    board: Leaderboard
    json_path: Path
    png_path: Path
    trained: dict  # model name -> training summary

    def table(self) -> str:
        return self.board.table()


def load_spec(path: Path) -> dict:
    path = Path(path)
    try:
        spec = tomllib.loads(path.read_text())
    except FileNotFoundError as exc:
        raise RacerlabError(f"{path}: no such sweep spec; write one (see `racerlab sweep --help`)") from exc
    except tomllib.TOMLDecodeError as exc:
        raise RacerlabError(f"{path}: not valid TOML ({exc}); fix the line it names") from exc
    models = spec.get("model") or []
    if not models:
        raise RacerlabError(f"{path}: no [[model]] entries; add at least one [[model]] with a name")
    if not isinstance(models, list) or not all(isinstance(m, dict) for m in models):
        raise RacerlabError(f"{path}: model must be [[model]] tables, each with a name; see `racerlab sweep --help`")
    names = set()
    for n, m in enumerate(models):
        if "name" not in m:
            raise RacerlabError(f"{path}: [[model]] number {n + 1} has no name; add name = \"...\"")
        if not isinstance(m["name"], str) or not _NAME.fullmatch(m["name"]):
            raise RacerlabError(f"{path}: [[model]] number {n + 1}: name = {m['name']!r} is not a folder name; give "
                                "letters, digits, '.', '_' or '-' (the model's folder goes into the sweep's out)")
        unknown = set(m) - _MODEL_KEYS
        if unknown:
            raise RacerlabError(f"{path}: model {m['name']!r} has unknown key {sorted(unknown)[0]!r}; "
                                f"use {', '.join(sorted(_MODEL_KEYS))}")
        if m["name"] in names:
            raise RacerlabError(f"{path}: model name {m['name']!r} appears twice; give each model its own name")
        names.add(m["name"])
    rule_names = {f.name for f in fields(RaceRules)}
    bad = set(spec.get("race", {})) - rule_names
    if bad:
        raise RacerlabError(f"{path}: [race] has unknown key {sorted(bad)[0]!r}; use {', '.join(sorted(rule_names))}")
    _check_values(path, spec)
    return spec


def _check_values(path: Path, spec: dict) -> None:
    """Every value a sweep uses after its trainings, checked before the first one starts."""
    try:
        RaceRules(**spec.get("race", {}))
    except (RacerlabError, TypeError, ValueError) as exc:
        raise RacerlabError(f"{path}: [race] {exc}; fix it before the models train") from None
    for key, default in (("iterations", 2), ("cars", 4)):
        value = spec.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 10_000:
            raise RacerlabError(f"{path}: {key} = {value!r}; give a whole number from 1 to 10000")
    for key in ("out", "track"):
        if key in spec and (not isinstance(spec[key], str) or not spec[key].strip()):
            raise RacerlabError(f"{path}: {key} = {spec[key]!r}; give a folder or track name as a string")
    for m in spec["model"]:
        if "reward" in m and not (path.parent / str(m["reward"])).is_file():
            raise RacerlabError(f"{path}: model {m['name']!r}: reward file {path.parent / str(m['reward'])} does not "
                                "exist; fix the path")
        if not isinstance(m.get("hyperparameters", {}), dict):
            raise RacerlabError(f"{path}: model {m['name']!r}: hyperparameters must be a table, e.g. "
                                "hyperparameters = { lr = 0.001 }")


def prepare_models(spec_path: Path, spec: dict) -> list[Path]:
    """A new model folder for each entry in the spec's `out`. A folder that is there already (an earlier model, an
    earlier sweep's) is refused before any is written, and on an error the folders made so far are removed:
    a sweep never re-initialises a model."""
    out = (spec_path.parent / spec.get("out", spec_path.stem)).resolve()
    for m in spec["model"]:
        there = out / m["name"]
        if there.exists() and not (there.is_dir() and not any(there.iterdir())):
            raise RacerlabError(f"{spec_path}: model {m['name']!r}: {there} is there already; a sweep trains new "
                                "models only: give another name or out, or move that folder away")
    made: list[Path] = []
    try:
        for m in spec["model"]:
            made.append(out / m["name"])
            prepare_model(spec_path, out, m, spec.get("track"), spec.get("cars", 4))
    except BaseException:
        for d in made:
            shutil.rmtree(d, ignore_errors=True)
        raise
    return made


def prepare_model(spec_path: Path, out: Path, entry: dict, track: str, cars: int) -> Path:
    """An ordinary model folder for one sweep entry: init defaults, then the entry's reward and hyperparameters."""
    folder = init_model(out / entry["name"], track=track, num_cars=cars,
                        **{k: entry[k] for k in _INIT_KEYS if k in entry})
    if "reward" in entry:
        src = (spec_path.parent / entry["reward"]).resolve()
        if not src.is_file():
            raise RacerlabError(f"{spec_path}: model {entry['name']!r}: reward file {src} does not exist; fix the path")
        folder.write_reward(src.read_text())
    hp_over = entry.get("hyperparameters") or {}
    if hp_over:
        hp = json.loads(folder.hyperparameters_path.read_text())
        unknown = set(hp_over) - set(hp)
        if unknown:
            raise RacerlabError(f"{spec_path}: model {entry['name']!r}: unknown hyperparameter {sorted(unknown)[0]!r}; "
                                f"use one of {', '.join(sorted(hp))}")
        hp.update(hp_over)
        folder.write_hyperparameters(hp)
        folder.hyperparameters()  # validates the values, naming the file
    return folder.path


def _train_one(model_dir: str, iterations: int) -> dict:
    import torch

    from racerlab.train import train

    torch.set_num_threads(1)
    r = train(model_dir, progress=False, iterations=iterations)
    return {"iterations": r.iterations, "episodes": r.episodes, "env_steps": r.env_steps,
            "wall_seconds": round(r.wall_seconds, 2), "best_checkpoint": r.best_checkpoint}


def run_sweep(spec_path, address: str | None = None, *, stall_s: float = TRAINING_STALL_S,
              start_s: float = TRAINING_STALL_S, note=print, tick_s: float = 2.0) -> SweepBoard:
    """Train the spec's models in parallel on Ray and race them. A training with no progress for `stall_s` after
    it started, or not started while no training moved for `start_s`, is given up and left out of the race
    (`note` says so; its entry in `trained` says why)."""
    spec_path = Path(spec_path)
    spec = load_spec(spec_path)
    out = (spec_path.parent / spec.get("out", spec_path.stem)).resolve()
    track = spec.get("track")
    dirs = prepare_models(spec_path, spec)
    names = [m["name"] for m in spec["model"]]
    ray = connect(address)
    task = ray.remote(num_cpus=1, max_retries=1)(_train_one)
    watch = _Watch(ray, spec_path, names, dirs, (stall_s, start_s), note)
    trained = watch.run([task.remote(str(d), int(spec.get("iterations", 2))) for d in dirs], tick_s)
    raced = [d for d, n in zip(dirs, names, strict=True) if "failed" not in trained[n]]
    if not raced:
        raise RacerlabError(f"{spec_path}: no training finished; model {names[0]!r}: {trained[names[0]]['failed']}; "
                            "check `ray status` and the workers' logs under the Ray session folder, then run the "
                            "sweep again")
    rules = RaceRules(**spec.get("race", {}))
    board = race(raced, track=track, rules=rules, out=out / "leaderboard.json")
    data = json.loads(board.path.read_text())
    for row in data["leaderboard"]:
        row["training"] = trained.get(row["model"])
    data["left_out"] = {n: t["failed"] for n, t in trained.items() if "failed" in t}
    board.path.write_text(json.dumps(data, indent=2) + "\n")
    png = draw_leaderboard(board, out / "leaderboard.png")
    return SweepBoard(board, board.path, png, trained)


class _Watch:
    """Waits for the sweep's training tasks, never unboundedly: a training is judged by its model folder (the
    lock it takes when it starts, then a checkpoint or a metrics line each iteration). One that started and shows
    nothing new for `stall_s`, or one not started while no training at all has moved for `start_s` (no free CPU;
    starting a worker, its imports and worlds, takes a while), is cancelled (its worker killed) and recorded as
    failed."""

    def __init__(self, ray, spec_path: Path, names: list[str], dirs: list[Path], limits: tuple[float, float], note):
        self.ray, self.spec_path, self.names, self.dirs = ray, spec_path, names, dirs
        (self.stall_s, self.start_s), self.note = limits, note
        self.marks = [_progress(d) for d in dirs]  # as the folder was before its training began
        self.lock_before = [m[0] for m in self.marks]  # a stale lock left by an earlier run is not a start
        self.started = [False] * len(dirs)

    def run(self, refs: list, tick_s: float) -> dict:
        index = {ref: k for k, ref in enumerate(refs)}
        trained: dict[str, dict] = {}
        now = time.monotonic()
        seen, latest = [now] * len(refs), now
        pending = list(refs)
        while pending:
            done, pending = self.ray.wait(pending, num_returns=1, timeout=tick_s)
            now = time.monotonic()
            for ref in done:
                trained[self.names[index[ref]]] = self._result(ref, index[ref])
                latest = now
            for ref in pending:
                k = index[ref]
                mark = _progress(self.dirs[k])
                if mark != self.marks[k]:
                    self.marks[k], seen[k], latest = mark, now, now
                    self.started[k] = self.started[k] or mark[0] != self.lock_before[k]
            stalled = [ref for ref in pending if (now - seen[index[ref]] > self.stall_s if self.started[index[ref]]
                                                  else now - latest > self.start_s)]
            for ref in stalled:
                trained[self.names[index[ref]]] = self._give_up(ref, index[ref])
                pending.remove(ref)
        return {n: trained[n] for n in self.names}

    def _result(self, ref, k: int) -> dict:
        where = f"{self.spec_path}: model {self.names[k]!r}"
        try:
            return self.ray.get(ref, timeout=READY_GET_S)  # finished: its result is already there
        except self.ray.exceptions.RayTaskError as exc:
            raise remote_error(exc, where) from None
        except (self.ray.exceptions.RayActorError, self.ray.exceptions.WorkerCrashedError,
                self.ray.exceptions.GetTimeoutError) as exc:
            return self._failed(k, f"its worker died ({type(exc).__name__})")

    def _give_up(self, ref, k: int) -> dict:
        self.ray.cancel(ref, force=True)  # kills the worker, stopped (SIGSTOP) or hung; its lock goes stale
        if self.started[k]:
            return self._failed(k, f"its training made no progress for {self.stall_s:.0f} s after it started (a "
                                   "stopped or hung Ray worker)")
        return self._failed(k, f"its training did not start within {self.start_s:.0f} s (no free CPU on the "
                               "cluster, or a worker that cannot start)")

    def _failed(self, k: int, why: str) -> dict:
        self.note(f"{self.spec_path}: model {self.names[k]!r}: {why}; it is left out of the race, its folder keeps "
                  "the iterations it finished (resume it with racerlab train)")
        return {"failed": why}


def _progress(path: Path) -> tuple:
    """What changes in a model folder as its training goes: the lock's content (the trainer's PID), then the
    checkpoints folder and metrics.jsonl with each iteration."""
    folder = ModelFolder(path)
    try:
        lock = folder.lock_path.read_text()
    except OSError:
        lock = None
    return lock, _mtime(folder.checkpoints_dir), _mtime(metrics_jsonl_path(path))


def _mtime(path: Path) -> int | None:
    try:
        return path.stat().st_mtime_ns
    except OSError:
        return None


def draw_leaderboard(board: Leaderboard, path: Path) -> Path:
    """Each model's best lap and average of its ranking laps (left) and incidents (right), best first."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = board.rows()
    names = [r["model"] for r in rows]
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 0.6 * len(rows) + 2), sharey=True,
                               gridspec_kw={"width_ratios": [2, 1]})
    y = np.arange(len(rows))
    best = [r["best_lap"] or 0.0 for r in rows]
    avg = [r["ranking_average"] or 0.0 for r in rows]
    a.barh(y - 0.2, best, height=0.4, color="tab:green", label="best lap")
    a.barh(y + 0.2, avg, height=0.4, color="tab:olive", label=f"average of {board.ranking_laps} laps")
    for k, r in enumerate(rows):
        a.text(best[k], k - 0.2, f" {r['best_lap']:.3f} s" if r["best_lap"] else " no lap", va="center")
        a.text(avg[k], k + 0.2, f" {r['ranking_average']:.3f} s" if r["ranking_average"] else " -", va="center")
    a.set_xlabel("lap time (s), shorter is better")
    a.set_yticks(list(y), [f"{r['rank']}. {n}" for r, n in zip(rows, names, strict=True)])
    a.invert_yaxis()
    a.set_xlim(0, 1.3 * max([*best, *avg, 1.0]))
    a.legend(loc="upper right", fontsize=8)  # the winner's bars, at the top, are the shortest
    b.barh(y, [r["off_track"] for r in rows], color="tab:red")
    b.set_xlabel("off-track incidents")
    penalty = board.rules.off_track_penalty
    fig.suptitle(f"sweep on {board.track}: {board.rules.trials} trials, continuous={board.rules.continuous}, "
                 f"off-track penalty {penalty:g} s")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
