"""The learner's curves of trained model folders, as PNGs for docs/learner.md, and the evaluation's own noise.

For each model folder given, writes <out>/<name>_learner.png (`analysis.plots.learner_health`: the policy's
spread, the value net's fit, how often training laps are as fast as the best evaluation lap, the best evaluation
lap in 1/15 s steps) and prints one JSON line: iterations, the best evaluation lap and where it fell in the run,
the evaluation laps of the last quarter (their spread is the evaluation's noise once the policy has settled), and
from the checkpoint left at the end, greedy laps from `--starts` start points spread over the lap (the same policy's
laps differ by where they start: how much one of the five in-training evaluation episodes can gain by its start).

Usage: python benchmarks/learner_curves.py MODEL [MODEL ...] [--out docs/img] [--starts 20]
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

from racerlab.analysis.episodes import episode_summary, iteration_summary, run_metrics, step_kinematics
from racerlab.analysis.load import load
from racerlab.analysis.plots import learner_health, save_png
from racerlab.analysis.report import fast_lap_share
from racerlab.spec import STEPS_PER_SECOND


def curves(model: Path, out: Path) -> dict:
    df = load(model)
    eps = episode_summary(df, step_kinematics(df))
    its = iteration_summary(eps, *run_metrics(model))
    its.index = its.index + 1  # numbered as the checkpoints and the training's lines
    eps = eps.assign(iteration=eps["iteration"] + 1)
    png = save_png(learner_health(its, fast_lap_share(eps, its), title=f"{model.name}: the learner"),
                   out / f"{model.name}_learner.png")
    laps = its["eval_best_lap"].dropna()
    steps = np.round(laps * STEPS_PER_SECOND).astype(int)
    last = steps[steps.index > 0.75 * len(its)]
    return {"model": str(model), "png": str(png), "iterations": len(its),
            "best_eval_lap_steps": int(steps.min()) if len(steps) else None,
            "best_first_at": int(steps.idxmin()) if len(steps) else None,
            "last_quarter_eval_lap_steps": {str(k): int(v) for k, v in last.value_counts().sort_index().items()}}


def start_spread(model: Path, starts: int) -> dict:
    """Greedy laps of the newest checkpoint from `starts` evenly spread start points (exact 1/15 s steps)."""
    from racerlab.model import ModelFolder
    from racerlab.train.evaluation import run_greedy_episodes
    from racerlab.train.loop import Trainer

    trainer = Trainer(model, progress=False)
    folder = ModelFolder(model)
    info = folder.checkpoints()[-1]
    trainer.agent.load_state_dict(folder.load_state(info).agent)
    world, n = trainer.eval_world, trainer.eval_world.sim.num_cars
    laps = []
    for first in range(0, starts, n):
        fractions = (first + np.arange(n)) / starts
        laps += [round(e.lap_time * STEPS_PER_SECOND) if e.status == "lap_complete" else None
                 for e in run_greedy_episodes(trainer.agent, world, fractions)]
    done = [s for s in laps[:starts] if s is not None]
    return {"checkpoint": info.name, "starts": starts, "laps_completed": len(done),
            "lap_steps_min_median_max": [min(done), int(np.median(done)), max(done)] if done else None}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, default=Path("docs") / "img")
    ap.add_argument("--starts", type=int, default=20, help="start points for the checkpoint's greedy laps (0: none)")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for model in args.models:
        row = curves(model, args.out)
        if args.starts:
            row["start_spread"] = start_spread(model, args.starts)
        row["loadavg_1min"] = round(os.getloadavg()[0], 2)
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
