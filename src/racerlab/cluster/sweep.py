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
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from racerlab.cluster.collector import connect
from racerlab.errors import RacerlabError
from racerlab.evaluate import Leaderboard, RaceRules, race
from racerlab.model import init_model

_INIT_KEYS = ("sensor", "action_space", "algorithm", "max_speed")
_MODEL_KEYS = {"name", "reward", "hyperparameters", *_INIT_KEYS}


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
    names = set()
    for n, m in enumerate(models):
        if "name" not in m:
            raise RacerlabError(f"{path}: [[model]] number {n + 1} has no name; add name = \"...\"")
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
    return spec


def prepare_model(spec_path: Path, out: Path, entry: dict, track: str, cars: int) -> Path:
    """An ordinary model folder for one sweep entry: init defaults, then the entry's reward and hyperparameters."""
    folder = init_model(out / entry["name"], track=track, num_cars=cars, force=True,
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


def run_sweep(spec_path, address: str | None = None) -> SweepBoard:
    spec_path = Path(spec_path)
    spec = load_spec(spec_path)
    out = (spec_path.parent / spec.get("out", spec_path.stem)).resolve()
    track = spec.get("track")
    cars = int(spec.get("cars", 4))
    dirs = [prepare_model(spec_path, out, m, track, cars) for m in spec["model"]]
    ray = connect(address)
    task = ray.remote(num_cpus=1, max_retries=1)(_train_one)
    trained = dict(zip([m["name"] for m in spec["model"]],
                       ray.get([task.remote(str(d), int(spec.get("iterations", 2))) for d in dirs]), strict=True))
    rules = RaceRules(**spec.get("race", {}))
    board = race(dirs, track=track, rules=rules, out=out / "leaderboard.json")
    data = json.loads(board.path.read_text())
    for row in data["leaderboard"]:
        row["training"] = trained.get(row["model"])
    board.path.write_text(json.dumps(data, indent=2) + "\n")
    png = draw_leaderboard(board, out / "leaderboard.png")
    return SweepBoard(board, board.path, png, trained)


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
