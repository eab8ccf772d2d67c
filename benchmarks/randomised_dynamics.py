"""Randomised dynamics: does a model trained on cars drawn from the fit's spread lap better on cars at its edges?

Trains one `features` model with `[car] randomise = 1` (each training episode draws the car's constants from the
fit's spread, `spec.CAR_SPREAD`) or without it (the fitted car), for `--minutes` on reInvent2019_track
(continuous actions up to 4 m/s, racing-line reward), then evaluates its best checkpoint (3 laps, exact steps) on
three cars: the fitted one and the two edges of the spread (every spread constant at -2 and at +2 spreads).
One JSON line per model and car: the best and mean lap time (penalties included), laps completed, resets.

    python benchmarks/randomised_dynamics.py --simulator console --minutes 4 --randomise 1   # one model
    python benchmarks/randomised_dynamics.py --simulator console --minutes 4 --randomise 0   # the other
"""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
from dataclasses import replace
from pathlib import Path

from racerlab.evaluate import evaluate
from racerlab.line import racing_line
from racerlab.model import init_model
from racerlab.model.config import CarSettings
from racerlab.reward import reward_source
from racerlab.sim.car import RANDOMISED, SPREAD_CLIP
from racerlab.spec import CAR_SPREAD, CarParams, car_params
from racerlab.train import train

REPO = Path(__file__).resolve().parents[1]
AWS_TRACKS = Path(os.environ.get("RACERLAB_TEST_AWS_TRACKS", REPO.parent / "shared" / "tracks"))
REINVENT = AWS_TRACKS / "reInvent2019_track.npy"


def edge_car(car: CarParams, sign: int) -> CarParams:
    """`car` with every constant of its spread moved SPREAD_CLIP spreads in the direction `sign`, no lower than the
    training draws go (`sim.car.RANDOMISED`); a constant that is off stays off, as in the draws."""
    spread = CAR_SPREAD[(car.simulator, car.control)]
    moved = {k: max(getattr(car, k) + sign * SPREAD_CLIP * sd, RANDOMISED[k][1]) for k, sd in spread.items()
             if not (getattr(car, k) == 0 and k in ("slide_mps", "accel_fade_mps", "tyre_sat_mps2"))}
    return replace(car, **moved)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--simulator", choices=["droa", "console"], default="console")
    ap.add_argument("--minutes", type=float, default=4.0)
    ap.add_argument("--randomise", type=float, default=1.0, help="[car] randomise of the trained model (0: off)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    car = car_params(args.simulator, "5", step_jitter=False)
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        folder = init_model(Path(tmp) / "m", track=str(REINVENT), sensor="features", max_speed=4.0,
                            action_space="continuous", best_model_metric="laptime")
        cfg = folder.config()
        table = (("randomise", args.randomise),) if args.randomise > 0 else ()
        cfg = replace(cfg, car=CarSettings(args.simulator, table), run=replace(cfg.run, seed=args.seed))
        folder.config_path.write_text(cfg.to_toml())
        line = racing_line(str(REINVENT), car=car)
        folder.write_reward(reward_source("racing_line", line, folder.metadata().actions.top_speed))
        r = train(folder.path, minutes=args.minutes, progress=False)
        for name, test_car in (("fitted", car), ("edge -2 spreads", edge_car(car, -1)),
                               ("edge +2 spreads", edge_car(car, +1))):
            res = evaluate(folder.path, trials=3, write=False, car=test_car)
            times = [lap.time for lap in res.laps if lap.completed]
            print(json.dumps({"bench": "randomised_dynamics", "trained_randomise": args.randomise,
                              "simulator": args.simulator, "minutes": args.minutes, "iterations": r.iterations,
                              "env_steps": r.env_steps, "test_car": name,
                              "best_lap_s": round(min(times), 3) if times else math.nan,
                              "mean_lap_s": round(sum(times) / len(times), 3) if times else math.nan,
                              "laps_completed": len(times), "trials": len(res.laps),
                              "resets": sum(lap.resets for lap in res.laps),
                              "loadavg_1min_before_after": [round(load_before, 2), round(os.getloadavg()[0], 2)]}),
                  flush=True)


if __name__ == "__main__":
    main()
