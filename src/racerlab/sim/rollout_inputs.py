"""The checks `sim.car.rollout` makes before it replays anything: a NaN or inf became a NaN path and a (4, 3) array
of actions was silently reshaped into (6, 2); a car with a billion sub-steps hung the compiled step."""

from __future__ import annotations

import math

import numpy as np

from racerlab.errors import ConfigError
from racerlab.spec import MAX_SUBSTEPS, CarParams


def check_rollout_inputs(start, actions, history, dt, car: CarParams) -> None:
    """One line naming the argument, its problem and the fix; nothing when the inputs make sense."""
    if not isinstance(start, dict):
        raise ConfigError(f"rollout: start must be a dict with x, y, heading and speed, got {type(start).__name__}")
    need = ["x", "y", "heading", "speed" if "mean_speed" not in start else "mean_speed"]
    for key in need:
        if key not in start:
            raise ConfigError(f"rollout: start has no {key!r}; give x, y (m), heading (°) and speed (m/s)")
    for key in (*need, "steering_angle", "yaw_rate", "mean_dt"):
        value = start.get(key)
        if value is not None and not _finite_number(value):
            raise ConfigError(f"rollout: start[{key!r}] = {value!r} is not a finite number")
    if "mean_dt" in start and not start["mean_dt"] > 0:
        raise ConfigError(f"rollout: start['mean_dt'] = {start['mean_dt']!r}; give the step's length in s (> 0)")
    k = len(_pairs("actions", actions, allow_empty=False))
    if history is not None and len(history):
        _pairs("history", history, allow_empty=True)
    if dt is not None:
        steps = np.asarray(dt, dtype=np.float64)
        if steps.size != k or not np.all(np.isfinite(steps)) or not np.all(steps > 0):
            raise ConfigError(f"rollout: dt must hold {k} step lengths (one per action), finite and > 0 s; got "
                              f"{steps.size} value(s)")
    if not 1 <= car.substeps <= MAX_SUBSTEPS:
        raise ConfigError(f"rollout: car.substeps = {car.substeps}; give 1 to {MAX_SUBSTEPS}")


def _finite_number(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | float | np.number) and math.isfinite(value)


def _pairs(name: str, value, allow_empty: bool) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"rollout: {name} must be numbers, [[steering_angle °, speed m/s], ...]") from None
    if arr.shape == (2,):
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[1] != 2 or (not allow_empty and len(arr) == 0):
        raise ConfigError(f"rollout: {name} must have shape (k, 2), one [steering_angle °, speed m/s] per row; got "
                          f"shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        row = int(np.flatnonzero(~np.isfinite(arr).all(axis=1))[0])
        raise ConfigError(f"rollout: {name} row {row} is {arr[row].tolist()}: not finite numbers")
    return arr
