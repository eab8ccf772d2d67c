"""Best evaluation lap after a fixed training time, beside racerlab's theoretical limit and the AWS record.

For each observation kind it creates a fresh model on reInvent2019_track (continuous actions, top speed
4 m/s, AWS default hyperparameters, the reward template given), trains for `--minutes`, and prints one
JSON line: the best greedy evaluation lap (exact 1/15 s steps), the theoretical limit of `racerlab line` for the
same car (the fastest lap the simulator's off-track rule allows), their ratio next to the target (features <= 1.05x,
camera <= 1.25x), the racing line's own lap (the line the racing_line reward follows: the limit's kind of path
`--line-margin` from the borders, as `racerlab init --reward racing_line` writes it), the all-time record in the AWS
simulator (7.198 s), when the best lap was reached (first and last iteration that drove it, and where the first
falls in the run) and the load: the load average before and after, and the CPU seconds the run got (a loaded
machine gives fewer iterations in the same minutes; read the ratio, and compare runs taken at a similar load).

Usage: python benchmarks/lap_near_limit.py [--kinds features camera] [--minutes 30] [--reward racing_line]
       [--line-margin M] [--seed N] [--keep DIR] [--track PATH] [--simulator droa|console] [--look aws|classic]
--keep: train in DIR/<kind> and keep the model folder (its metrics.jsonl holds the learning curves); default: a
temporary folder, removed.
--look: the camera's world (training.toml's run.look; default aws), recorded in the JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from racerlab.cli.model import reward_line
from racerlab.line import theoretical_limit
from racerlab.model import init_model
from racerlab.model.config import LOOKS, CarSettings
from racerlab.reward import TEMPLATES, reward_source
from racerlab.spec import car_params
from racerlab.train import train

REPO = Path(__file__).resolve().parents[1]
# the real AWS tracks beside the checkout, or where RACERLAB_TEST_AWS_TRACKS points (as the tests look)
AWS_TRACKS = Path(os.environ.get("RACERLAB_TEST_AWS_TRACKS", REPO.parent / "shared" / "tracks"))
REINVENT = AWS_TRACKS / "reInvent2019_track.npy"
AWS_RECORD_S = 7.198  # all-time best lap on reInvent2019_track in the AWS simulator (track_records.md)
TARGET_RATIO = {"features": 1.05, "camera": 1.25}


def best_lap(kind: str, track: Path, minutes: float, reward: str, limit_s: float, line, car,
             look: str = "aws", seed: int = 0, keep: Path | None = None) -> dict:
    load_before, cpu_before = os.getloadavg()[0], time.process_time()
    with tempfile.TemporaryDirectory() as tmp:
        where = keep / kind if keep else Path(tmp) / "m"
        folder = init_model(where, track=str(track), sensor=kind, max_speed=4.0, action_space="continuous",
                            best_model_metric="laptime")
        cfg = folder.config()  # the simulator's car drives (its [car] table)
        cfg = replace(cfg, run=replace(cfg.run, look=look, seed=seed))  # the camera's look (--look), --seed
        folder.config_path.write_text(replace(cfg, car=CarSettings(car.simulator)).to_toml())
        folder.write_reward(reward_source(reward, line, folder.metadata().actions.top_speed))
        r = train(folder.path, minutes=minutes, progress=False)
    laps = [(h["eval/best_lap"], h["iteration"], h["env_steps"]) for h in r.history if h.get("eval/best_lap")]
    best = min(laps) if laps else (float("nan"), None, None)
    again = [it for lap, it, _ in laps if abs(lap - best[0]) < 1 / 30]  # laps come in 1/15 s steps
    return {"bench": "lap_near_limit", "observation": kind, "look": look, "seed": seed, "track": track.stem,
            "minutes": minutes, "reward": reward, "iterations": r.iterations, "env_steps": r.env_steps,
            "best_eval_lap_s": round(best[0], 3), "best_at_iteration": best[1], "best_at_env_steps": best[2],
            "best_at_run_fraction": round(best[1] / r.iterations, 3) if best[1] else None,
            "best_last_iteration": max(again, default=None), "iterations_at_best": len(again),
            "theoretical_limit_s": round(limit_s, 3), "ratio_to_limit": round(best[0] / limit_s, 3),
            "racing_line_lap_s": round(line.lap_time, 3), "line_margin_m": line.margin_m, "line_method": line.method,
            "target_ratio": TARGET_RATIO.get(kind), "aws_record_s": AWS_RECORD_S, "car": car.name,
            "first_lap": r.first_lap, "loadavg_1min_before_after": [round(load_before, 2),
                                                                    round(os.getloadavg()[0], 2)],
            "cpu_seconds": round(time.process_time() - cpu_before, 1), "wall_seconds": round(r.wall_seconds, 1)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", nargs="+", default=["features", "camera"], choices=["features", "camera"])
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--reward", choices=list(TEMPLATES), default="racing_line")
    ap.add_argument("--line-margin", type=float, default=None,
                    help="racing_line: the line's margin to the borders, m (default: the template's, -0.1)")
    ap.add_argument("--seed", type=int, default=0, help="training.toml's run.seed (default 0)")
    ap.add_argument("--keep", type=Path, help="keep each model folder in DIR/<kind> (default: a temporary one)")
    ap.add_argument("--track", type=Path, default=REINVENT)
    ap.add_argument("--simulator", choices=["droa", "console"], default="droa", help="whose car (default droa)")
    ap.add_argument("--look", choices=list(LOOKS), default="aws", help="the camera's world (default aws)")
    args = ap.parse_args()
    car = car_params(args.simulator, "5")  # a new continuous model is version 5
    limit = theoretical_limit(str(args.track), car=car).lap_time
    line = reward_line(str(args.track), car, args.line_margin)
    for kind in args.kinds:
        print(json.dumps(best_lap(kind, args.track, args.minutes, args.reward, limit, line, car, args.look,
                                  args.seed, args.keep)),
              flush=True)


if __name__ == "__main__":
    main()
