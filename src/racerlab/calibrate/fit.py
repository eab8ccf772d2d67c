"""Fitting the car's constants to stretches of a real log, and measuring how well a car predicts them.

The loss is the mean of a robust distance (√(d² + 1 cm²)) between the replayed and the logged front point over
every step of every stretch: close to the median error the report gives, and smooth enough for Powell's method.
Each constant is searched within its row's `fit` range (`spec.CAR_CONSTANTS`, gathered in `BOUNDS`); the spread is
the standard deviation over fits on resampled episodes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import minimize

from racerlab.calibrate.data import Stretches
from racerlab.calibrate.floor import floor_errors
from racerlab.sim.car import pack, rollout_batch
from racerlab.spec import CAR_CONSTANTS, CarConstant, CarParams, car_params

HORIZONS = (1, 3, 8, 15)  # steps after which errors are reported


def fitted_rows(table: tuple[CarConstant, ...] = CAR_CONSTANTS) -> tuple[CarConstant, ...]:
    """The rows of `table` a fit searches (its `fit` column), in the order the search takes them."""
    return tuple(c for c in table if c.fit is not None)


def search_key(c: CarConstant) -> str:
    """The name of a fitted constant in the search: its own, or "1/name" for one searched as its inverse."""
    return f"1/{c.name}" if c.fit.inverse else c.name


def search_bounds(table: tuple[CarConstant, ...] = CAR_CONSTANTS) -> dict[str, tuple[float, float]]:
    """Where a fit searches each of `table`'s fitted constants: search key (`search_key`) -> (low, high)."""
    return {search_key(c): (c.fit.low, c.fit.high) for c in fitted_rows(table)}


# what is fitted, and where it is searched (the `fit` column of spec.CAR_CONSTANTS); `slide_mps`, `accel_fade_mps`
# and `tyre_sat_mps2` are searched as their inverses (0 = none)
FITTED = tuple(c.name for c in fitted_rows())
BOUNDS = search_bounds()
INVERSE = {search_key(c): c.name for c in fitted_rows() if c.fit.inverse}  # searched as 1 / x


def predict(st: Stretches, car: CarParams) -> np.ndarray:
    """(N, horizon, 3) front x, y, heading the car predicts for each stretch."""
    return rollout_batch(st.start, st.commands, st.commands.shape[1] - st.dts.shape[1], st.dts, pack(car), True,
                         st.mean_dt)


def errors(st: Stretches, car: CarParams) -> np.ndarray:
    """(N, horizon) distance (m) between the predicted and the logged front point."""
    p = predict(st, car)
    return np.hypot(p[..., 0] - st.target[..., 0], p[..., 1] - st.target[..., 1])


def constant_velocity_errors(st: Stretches) -> np.ndarray:
    """(N, horizon) errors of the guess that ignores the actions: the last velocity, extrapolated."""
    vel = (st.start[:, :2] - st.prev) / st.prev_dt[:, None]
    t = np.cumsum(st.dts, axis=1)
    guess = st.start[:, None, :2] + vel[:, None, :] * t[..., None]
    return np.hypot(guess[..., 0] - st.target[..., 0], guess[..., 1] - st.target[..., 1])


def medians(err: np.ndarray, horizons=HORIZONS) -> dict[int, float]:
    """Median error after each of `horizons` steps."""
    return {h: float(np.median(err[:, h - 1])) for h in horizons if h <= err.shape[1]}


MIN_EPISODES = 5  # fewer episodes than this give no interval: resampling two or three says nothing of the others


def median_interval(err: np.ndarray, episodes: np.ndarray, *, level: float = 0.9, draws: int = 2000,
                    seed: int = 0) -> tuple[float, float]:
    """How far the median of the per-stretch errors `err` (N,) can move with the episodes it was measured on: the
    central `level` interval of the median over `draws` resamples of the episodes (with replacement, each resample
    taking every stretch of the episodes it picks). Stretches of one episode move together, so a set of few
    episodes gives a wide interval however many stretches it has. With fewer than `MIN_EPISODES` episodes: (NaN,
    NaN), for resampling a handful only repeats them."""
    err = np.asarray(err, dtype=float)
    eps, inverse = np.unique(episodes, return_inverse=True)
    if len(eps) < MIN_EPISODES:
        return math.nan, math.nan
    members = [err[inverse == i] for i in range(len(eps))]
    rng = np.random.default_rng(seed)
    meds = np.array([np.median(np.concatenate([members[i] for i in rng.integers(0, len(eps), len(eps))]))
                     for _ in range(draws)])
    lo, hi = np.quantile(meds, [(1 - level) / 2, (1 + level) / 2])
    return float(lo), float(hi)


def _searched(base: CarParams) -> dict[str, tuple[float, float]]:
    """The bounds of what a fit from `base` searches: every constant of its table with a `fit` search, those marked
    `only_if_on` only for a car that has them (the tyres' saturation: the console cars, ROS 2's droa car has none, and
    on logs without it the extra freedom only lets the lags and the kick wander; the front wheels' drive: the console
    velocity car; the wheels' offset: the console effort car)."""
    bounds = search_bounds(base.TABLE)
    return {search_key(c): bounds[search_key(c)] for c in fitted_rows(base.TABLE)
            if not c.fit.only_if_on or base.has(c.name)}


def _to_vector(car: CarParams, keys) -> np.ndarray:
    rows = {search_key(c): c for c in fitted_rows(car.TABLE)}
    out = []
    for k, (lo, hi) in keys.items():
        value = getattr(car, rows[k].name)
        if rows[k].fit.inverse:
            value = 1.0 / value if value > 0 else 0.0
        out.append(min(max(value, lo), hi))
    return np.array(out)


def _to_car(base: CarParams, vec, keys) -> CarParams:
    rows = {search_key(c): c for c in fitted_rows(base.TABLE)}
    vals = {}
    for (k, (lo, hi)), v in zip(keys.items(), vec, strict=True):
        value = float(min(max(v, lo), hi))
        if rows[k].fit.inverse:
            value = 1.0 / value if value > 1e-3 else 0.0
        vals[rows[k].name] = value
    return replace(base, **vals)


def _loss(st: Stretches, car: CarParams) -> float:
    e = errors(st, car)
    return float(np.mean(np.sqrt(e * e + 1e-4)))


def fit_car(st: Stretches, base: CarParams, *, max_evals: int = 1500) -> CarParams:
    """The constants of `base` (those of its table with a `fit` search; the saturation, the front drive and the
    wheels' offset only when `base` has them, `_searched`) that best replay the stretches `st`."""
    if not math.isfinite(_loss(st, base)):
        raise ValueError("the starting car gives non-finite predictions")
    keys = _searched(base)
    res = minimize(lambda v: _loss(st, _to_car(base, v, keys)), _to_vector(base, keys), method="Powell",
                   bounds=list(keys.values()), options={"maxfev": max_evals, "xtol": 1e-3, "ftol": 1e-5})
    return _to_car(base, res.x, keys)


@dataclass
class Fit:
    """A fitted car with the spread of its constants and its errors on the held-out stretches."""

    car: CarParams
    spread: dict[str, float]  # standard deviation of each fitted constant over resampled fits
    held_out: dict[int, float]  # median error (m) after each of HORIZONS steps
    constant_velocity: dict[int, float]
    floor: dict[int, float]  # the fitted car corrected by a regression learned on the fit stretches (`learned_floor`)
    fit_stretches: int
    held_out_stretches: int
    held: Stretches | None = field(default=None, repr=False)  # the held-out stretches (the picture replays them)
    # the 90 % interval of the held-out median after the longest horizon over resampled held-out episodes
    # (`median_interval`), and how many episodes were held out
    held_out_interval: tuple[float, float] = (math.nan, math.nan)
    held_out_episodes: int = 0


def fit_with_spread(fit_st: Stretches, held_st: Stretches, simulator: str, version="5", *, resamples: int = 3,
                    seed: int = 0, max_evals: int = 1500) -> Fit:
    """Fit `simulator`'s car for a `version` model on `fit_st`, its spread on `resamples` bootstrap resamples of the
    fit episodes, and its held-out errors on `held_st`."""
    base = car_params(simulator, version, step_jitter=False)
    car = fit_car(fit_st, base, max_evals=max_evals)
    rng = np.random.default_rng(seed)
    eps = np.unique(fit_st.episode)
    samples = []
    for _ in range(resamples if len(eps) > 1 else 0):
        pick = rng.choice(eps, size=len(eps), replace=True)
        idx = np.concatenate([np.flatnonzero(fit_st.episode == e) for e in pick])
        samples.append(fit_car(fit_st.take(idx), car, max_evals=max_evals // 3))
    spread = {c.name: float(np.std([getattr(s, c.name) for s in samples])) if samples else math.nan
              for c in fitted_rows(car.TABLE)}
    err = errors(held_st, car)
    return Fit(car, spread, medians(err), medians(constant_velocity_errors(held_st)),
               learned_floor(fit_st, held_st, car), len(fit_st), len(held_st), held_st,
               median_interval(err[:, -1], held_st.episode), len(np.unique(held_st.episode)))


def learned_floor(fit_st: Stretches, held_st: Stretches, car: CarParams, horizons=HORIZONS) -> dict[int, float]:
    """Median held-out error (m) after each of `horizons` steps of `car` corrected by a regression learned on the
    fit stretches of the same log (`calibrate.floor`): what a model of this log's motions could still gain."""
    return medians(floor_errors(fit_st, held_st, predict(fit_st, car), predict(held_st, car), horizons), horizons)
