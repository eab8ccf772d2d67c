"""Car fidelity: how far racerlab's car lands from the real simulator's front point, per shared log set.

Each set's episodes are split (every third held out, `racerlab.calibrate.split`); the table reports the median
front-point error on the held-out stretches after 1, 3, 8 and 15 steps (15 = 1 s) for: racerlab's car before
issue 24 (zero delay, τ 0.03 s, full kinematic steering), before issue 34 (the cars of 4b81135, the logs read with
the naive step timing tstamp_{j+1} - tstamp_j), the built-in car of the set's simulator and model version read by
its simulator's timing rule (after), the constant-velocity guess and a learned floor (the built-in car corrected
by a regression learned on the set's own fit episodes, `calibrate.learned_floor`). One JSON line per set, with
`after_1s_interval_m`: how far the figure after 1 s would move with other episodes (the central 90 % of the median
over resampled held-out episodes, `calibrate.median_interval`; null below 5 episodes).

    python benchmarks/car_fidelity.py              # before / after / constant velocity / floor per set
    python benchmarks/car_fidelity.py --fit        # refit the built-in cars on the fit episodes (spec.CAR_TABLE)
    python benchmarks/car_fidelity.py --cv         # every episode held out once: 3 fits per car, the sets' medians

`--cv` answers how much a set's figure owes to which episodes were held out (a set of few episodes, such as DRoA
2026 training with 22 held-out stretches from 2 episodes, can draw an easy or a hard third): for each car (one per
simulator and control, as `--fit` groups the sets) it fits the built-in car's constants three times, each time
holding out another third of every set's episodes (`split(..., fold=r)`; fold 1 is the default split), and reports
per set the median error over all its stretches, each predicted by the fit that did not see its episode, beside the
default split's figure of the same procedure, and the interval of the cross-validated figure over resampled
episodes.

Target (issue 34): after 1 s <= 0.10 m on the slow sets and <= 0.15 m on the fast console sets; after one step no
worse than constant velocity on every set.
"""

from __future__ import annotations

import argparse
import json
import tarfile
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from racerlab.calibrate import (
    HORIZONS,
    constant_velocity_errors,
    errors,
    fit_car,
    fit_with_spread,
    learned_floor,
    load_stretches,
    median_interval,
    medians,
)
from racerlab.calibrate.data import concat, split
from racerlab.sim.car import TIMINGS, log_timing
from racerlab.spec import CarParams, car_params, control_of

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "reference"
FAST = "simtraces/console2025oct-v5-highspeed"  # other racers' console runs at up to 3.5-4 m/s (issue 34)
# name: (paths, simulator, model version)
SETS = {
    "drfc2022-v4": (["real_logs/sample-drfc-1-logs"], "console", "4"),
    "console2022": (["real_logs/sample-console-logs"], "console", "4"),
    "console2025-v5": (["simtraces/console2025aug-v5-ros1-2022_reinvent_champ_ccw"], "console", "5"),
    "console2025-fast-3.5": ([f"{FAST}/deepModel-clone3"], "console", "5"),
    "console2025-fast-4a": ([f"{FAST}/reinvencementModel-clone1/training"], "console", "5"),
    "console2025-fast-4b": ([f"{FAST}/vitor"], "console", "5"),
    "droa2026-training": (["simtraces/droa2026-v6-Spain_track"], "droa", "5"),
    "droa2026-evaluation": (["simtraces/droa2026-v6-Spain_track-evaluation"], "droa", "5"),
    "droa2026-eval-only-tar": (["real_logs/sample-droa-eval-only.tar.gz"], "droa", "5"),
}
# sets reported as one besides their parts: the DRoA 2026 download (sample-droa-solution-logs: a training run and an
# evaluation of its model), its parts' held-out stretches together (their fit stretches for the floor)
WHOLE = {"droa2026": ("droa2026-training", "droa2026-evaluation")}
EPISODE_BLOCK = 1_000_000  # episode numbers of the i-th part of a WHOLE set start at i * EPISODE_BLOCK
# racerlab's car before issue 24
BEFORE = CarParams(delay_steps=0.0, steer_tau_s=0.03, yaw_gain=1.0, slide_mps=0.0, yaw_tau_s=0.0, speed_tau_s=0.1,
                   accel_mps2=3.0, brake_mps2=4.9, ground_factor=1.0, wheel_cap_mps=4.0, accel_fade_mps=0.0,
                   step_jitter=False)
# racerlab's cars before issue 34 (4b81135: spec.CAR_TABLE then), read with the naive step timing
BEFORE_34 = {
    ("droa", "velocity"): {},
    ("console", "velocity"): {"simulator": "console", "delay_steps": 0.76, "steer_tau_s": 0.068, "yaw_gain": 0.740,
                              "slide_mps": 1.49, "yaw_tau_s": 0.0, "speed_tau_s": 0.0005, "accel_mps2": 22.0,
                              "brake_mps2": 30.0, "ground_factor": 1.054},
    ("console", "effort"): {"simulator": "console", "control": "effort", "delay_steps": 0.29, "steer_tau_s": 0.045,
                            "yaw_gain": 0.672, "slide_mps": 6.26, "yaw_tau_s": 0.469, "speed_tau_s": 0.129,
                            "accel_mps2": 30.0, "brake_mps2": 18.7, "ground_factor": 0.981, "wheel_cap_mps": 4.0},
}
DROA_V5_BEFORE_34 = dict(delay_steps=0.69, steer_tau_s=0.158, yaw_gain=0.632, slide_mps=0.0, yaw_tau_s=0.0,
                         speed_tau_s=0.0065, accel_mps2=21.6, brake_mps2=29.3, ground_factor=1.014)


def before_34(simulator: str, version: str) -> CarParams:
    """racerlab's car of `simulator` and `version` at 4b81135."""
    table = BEFORE_34[(simulator, control_of(version))] or {"simulator": simulator, **DROA_V5_BEFORE_34}
    return CarParams(**{"step_jitter": False, "accel_fade_mps": 0.0, **table})


def _paths(rel: list[str], tmp: Path) -> list[Path]:
    out = []
    for r in rel:
        p = SHARED / r
        if p.name.endswith(".tar.gz"):
            with tarfile.open(p) as tar:
                tar.extractall(tmp / p.name, filter="data")
            p = next((tmp / p.name).iterdir())
        out.append(p)
    return out


def _timing(name: str, rule: str) -> str:
    """The step timing a set is read with: its simulator's rule (`sim.car.LOG_TIMING`), or `rule` for all."""
    return log_timing(car_params(SETS[name][1], SETS[name][2])) if rule == "simulator" else rule


def _round(d: dict) -> dict:
    return {str(k): round(v, 4) for k, v in d.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fit", action="store_true", help="refit the built-in cars (one per simulator and control)")
    ap.add_argument("--cv", action="store_true", help="3-fold cross-validation of the fit (every episode held out "
                    "once)")
    ap.add_argument("--every", type=int, default=None, help="a stretch starts at every N-th row (default: about "
                    "2 500 stretches per set)")
    ap.add_argument("--sets", nargs="*", default=list(SETS))
    ap.add_argument("--timing", default="simulator", choices=("simulator", *TIMINGS),
                    help="how the logs' tstamps give step lengths (default: each simulator's rule)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        raw = {n: load_stretches(_paths(SETS[n][0], Path(tmp)), args.every, _timing(n, args.timing))
               for n in args.sets}
        naive = {} if args.fit or args.cv else {
            n: split(load_stretches(_paths(SETS[n][0], Path(tmp)), args.every, "next"))[1] for n in args.sets}
    if args.cv:
        for (sim, control), names in _groups(args.sets).items():
            _cross_validate(sim, control, {n: raw[n] for n in names})
        return
    loaded = {n: split(st) for n, st in raw.items()}
    if args.fit:
        for (sim, control), names in _groups(args.sets).items():
            fit = concat([loaded[n][0] for n in names])
            held = concat([loaded[n][1] for n in names])
            f = fit_with_spread(fit, held, sim, "5" if control == "velocity" else "4", resamples=2)
            print(json.dumps({"simulator": sim, "control": control, "sets": names, "fit_stretches": f.fit_stretches,
                              "constants": {k: round(getattr(f.car, k), 4) for k in f.spread},
                              "spread": {k: round(v, 4) for k, v in f.spread.items()},
                              "held_out": _round(f.held_out), "constant_velocity": _round(f.constant_velocity),
                              "learned_floor": _round(f.floor)}),
                  flush=True)
        return
    for n in args.sets:
        _report(n, *loaded[n], naive.get(n))
    for whole, parts in WHOLE.items():
        if all(p in loaded for p in parts):
            _report(whole, concat([_apart(loaded[p][0], i) for i, p in enumerate(parts)]),
                    concat([_apart(loaded[p][1], i) for i, p in enumerate(parts)]),
                    concat([naive[p] for p in parts]) if naive else None)


def _apart(st, i: int):
    """`st` with its episode numbers moved out of the way of the other parts of a set reported as one (their
    logs number episodes from 0 each), so that the interval resamples them as the different episodes they are."""
    return replace(st, episode=st.episode + i * EPISODE_BLOCK)


def _groups(names: list[str]) -> dict[tuple[str, str], list[str]]:
    """The sets by the car that drives them (simulator, control), the DRoA tar left out beside the folder it
    repeats."""
    groups: dict[tuple[str, str], list[str]] = {}
    for n in names:
        groups.setdefault((SETS[n][1], control_of(SETS[n][2])), []).append(n)
    for names_ in groups.values():
        if "droa2026-eval-only-tar" in names_ and len(names_) > 1:
            names_.remove("droa2026-eval-only-tar")  # the same runs as droa2026-evaluation
    return groups


def _cross_validate(sim: str, control: str, sets: dict) -> None:
    """Three fits of the `sim`/`control` car, each on two thirds of every set's episodes; one JSON line per set: the
    median error after each horizon over all its stretches, each from the fit that held its episode out."""
    base = car_params(sim, "5" if control == "velocity" else "4", step_jitter=False)
    held_err: dict[str, list] = {n: [] for n in sets}
    held_eps: dict[str, list] = {n: [] for n in sets}
    default: dict[str, dict] = {}
    for fold in range(3):
        parts = {n: split(st, fold=fold) for n, st in sets.items()}
        car = fit_car(concat([p[0] for p in parts.values()]), base)
        for n, (_, held) in parts.items():
            err = errors(held, car)
            held_err[n].append(err)
            held_eps[n].append(held.episode)
            if fold == 1:
                default[n] = _round(medians(err))
    for whole, parts in WHOLE.items():
        if all(p in held_err for p in parts):
            held_err[whole] = [np.concatenate(fold) for fold in zip(*(held_err[p] for p in parts), strict=True)]
            held_eps[whole] = [np.concatenate([e + i * EPISODE_BLOCK for i, e in enumerate(fold)])
                               for fold in zip(*(held_eps[p] for p in parts), strict=True)]
            default[whole] = _round(medians(held_err[whole][1]))
    for n, errs in held_err.items():
        print(json.dumps({"set": n, "car": base.name, "stretches": sum(len(e) for e in errs),
                          "held_out_per_fold": [len(e) for e in errs],
                          "cross_validated_m": _round(medians(np.concatenate(errs))),
                          "episodes": len(np.unique(np.concatenate(held_eps[n]))),
                          "cross_validated_1s_interval_m": _interval(np.concatenate(errs)[:, -1],
                                                                     np.concatenate(held_eps[n])),
                          "per_fold_1s_m": [round(float(np.median(e[:, -1])), 4) if len(e) else None for e in errs],
                          "default_split_m": default[n]}), flush=True)


def _interval(err, episodes) -> list[float] | None:
    """The 90 % interval of the median error over resampled episodes (`calibrate.median_interval`), rounded; None
    for a set of too few episodes."""
    lo, hi = median_interval(err, episodes)
    return [round(lo, 4), round(hi, 4)] if np.isfinite(lo) else None


def _report(n: str, fit_st, held, naive_held) -> None:
    _, sim, version = SETS[WHOLE[n][0] if n in WHOLE else n]
    after = car_params(sim, version, step_jitter=False)
    row = {"set": n, "simulator": sim, "version": version, "car": after.name, "fit_stretches": len(fit_st),
           "held_out_stretches": len(held), "horizons_steps": list(HORIZONS),
           "before_24_m": _round(medians(errors(held, BEFORE)))}
    if naive_held is not None:
        row["before_34_m"] = _round(medians(errors(naive_held, before_34(sim, version))))
    err = errors(held, after)
    row.update({"held_out_episodes": len(np.unique(held.episode)), "after_m": _round(medians(err)),
                "after_1s_interval_m": _interval(err[:, -1], held.episode),
                "constant_velocity_m": _round(medians(constant_velocity_errors(held))),
                "learned_floor_m": _round(learned_floor(fit_st, held, after))})
    print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
