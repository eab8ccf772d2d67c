"""Best evaluation lap after a fixed training time, beside racerlab's theoretical limit and the AWS record.

For each observation kind it creates a fresh model on reInvent2019_track (continuous actions, top speed
4 m/s, AWS default hyperparameters, the reward template given), trains for `--minutes`, and prints one
JSON line: the best greedy evaluation lap (exact 1/15 s steps), the theoretical limit of `racerlab line` for the
same car (the fastest lap the simulator's off-track rule allows), their ratio next to the target (features <= 1.05x,
camera <= 1.15x), the racing line's own lap (the line the racing_line reward follows: the limit's kind of path
`--line-margin` from the borders, as `racerlab init --reward racing_line` writes it), the all-time record in the AWS
simulator (7.198 s), when the best lap was reached (first and last iteration that drove it, and where the first
falls in the run) and the load average before and after (a loaded machine gives fewer iterations in the same
minutes; read the ratio, and compare runs taken at a similar load).

A camera model learns from a features teacher it trains itself, inside the same minutes (training.toml's
`[teacher] model = "teacher"`, what `racerlab init --sensor camera` writes; docs/learner.md, "A camera model from
a features teacher"); `--no-teacher` trains it by PPO alone, as before. The JSON also gives the process's CPU
seconds (user + system, children included) beside the wall time, since the machine may be shared.

Usage: python benchmarks/lap_near_limit.py [--kinds features camera] [--minutes 30] [--reward racing_line]
       [--line-margin M] [--track PATH] [--simulator droa|console] [--look aws|classic] [--device auto|cpu|cuda]
       [--keep DIR] [--no-teacher] [--seed N]
--look: the camera's world (training.toml's run.look; default aws), recorded in the JSON.
--keep DIR: keep each trained model folder as DIR/<kind> (for `racerlab evaluate`, `export`, ...).
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
TARGET_RATIO = {"features": 1.05, "camera": 1.15}


def _cpu_seconds() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _train_model(path: Path, kind: str, track: Path, minutes: float, reward: str, line, car, look: str,
                 device: str, teacher: bool, seed: int = 0):
    folder = init_model(path, track=str(track), sensor=kind, max_speed=4.0, action_space="continuous",
                        best_model_metric="laptime")
    cfg = folder.config()  # the simulator's car drives (its [car] table)
    cfg = replace(cfg, run=replace(cfg.run, look=look, device=device, seed=seed))  # --look, --device, --seed
    if not teacher:
        cfg = replace(cfg, teacher=replace(cfg.teacher, model=""))
    folder.config_path.write_text(replace(cfg, car=CarSettings(car.simulator)).to_toml())
    folder.write_reward(reward_source(reward, line, folder.metadata().actions.top_speed))
    return train(folder.path, minutes=minutes, progress=bool(os.environ.get("RACERLAB_BENCH_PROGRESS")))


def best_lap(kind: str, track: Path, minutes: float, reward: str, limit_s: float, line, car,
             look: str = "aws", device: str = "auto", keep: Path | None = None, teacher: bool = True,
             seed: int = 0) -> dict:
    load_before = os.getloadavg()[0]
    cpu0, wall0 = _cpu_seconds(), time.perf_counter()
    if keep is not None:
        r = _train_model(keep / kind, kind, track, minutes, reward, line, car, look, device, teacher, seed)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            r = _train_model(Path(tmp) / "m", kind, track, minutes, reward, line, car, look, device, teacher,
                              seed)
    cpu_s, wall_s = _cpu_seconds() - cpu0, time.perf_counter() - wall0
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
            "first_lap": r.first_lap, "device": device, "teacher": teacher and kind != "features",
            "wall_s": round(wall_s, 1), "cpu_s": round(cpu_s, 1), "kept": str(keep / kind) if keep else None,
            "loadavg_1min_before_after": [round(load_before, 2), round(os.getloadavg()[0], 2)]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", nargs="+", default=["features", "camera"], choices=["features", "camera"])
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--reward", choices=list(TEMPLATES), default="racing_line")
    ap.add_argument("--line-margin", type=float, default=None,
                    help="racing_line: the line's margin to the borders, m (default: the template's, -0.1)")
    ap.add_argument("--track", type=Path, default=REINVENT)
    ap.add_argument("--simulator", choices=["droa", "console"], default="droa", help="whose car (default droa)")
    ap.add_argument("--look", choices=list(LOOKS), default="aws", help="the camera's world (default aws)")
    ap.add_argument("--device", choices=["auto", "cpu", "cuda"], default="auto", help="where the networks train")
    ap.add_argument("--keep", type=Path, help="keep each trained model folder as DIR/<kind>")
    ap.add_argument("--no-teacher", action="store_true", help="a camera model learns by PPO alone (no teacher)")
    ap.add_argument("--seed", type=int, default=0, help="training.toml's run.seed (a second run: another seed)")
    args = ap.parse_args()
    car = car_params(args.simulator, "5")  # a new continuous model is version 5
    limit = theoretical_limit(str(args.track), car=car).lap_time
    line = reward_line(str(args.track), car, args.line_margin)
    for kind in args.kinds:
        result = best_lap(kind, args.track, args.minutes, args.reward, limit, line, car, args.look, args.device,
                          args.keep, not args.no_teacher, args.seed)
        print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
