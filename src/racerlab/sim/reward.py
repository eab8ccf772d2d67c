"""Reward functions: building AWS params, calling the racer's function, checking results (the file is loaded by
`racerlab.model.reward`).

The params dict holds every key the AWS simulator passes (facts §1) with the code's semantics;
`ParamsBuilder` makes one dict per car from the simulator's params table in bulk (columns are
turned into Python lists once, then `racerlab.spec.ParamsMaker` makes the dicts), and `RewardCaller` calls the
function, checks the value and turns any failure into a `RewardFunctionError` that names the
file and line and shows the step's params.
"""

from __future__ import annotations

import copy
import difflib
import math
import numbers
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from racerlab.errors import RewardFunctionError
from racerlab.model.reward import error_location, load_reward_function
from racerlab.sim import _kernels as K
from racerlab.sim.objects import base_from_model_point
from racerlab.spec import NO_OBJECTS, ParamsMaker

MAX_ABS_REWARD = 1e5


def as_reward_function(value) -> Callable[[dict], float] | None:
    """A callable, a path to a .py file, or None (no reward and no params: the fastest path)."""
    if value is None or callable(value):
        return value
    return load_reward_function(value)


def describe_exception(exc: BaseException, params: dict) -> str:
    """'reward_function raised KeyError: ...', with the likely fix when a params key is misspelt."""
    text = f"reward_function raised {type(exc).__name__}: {exc}"
    key = exc.args[0] if isinstance(exc, KeyError) and len(exc.args) == 1 else None
    if isinstance(key, str) and key not in params:
        close = difflib.get_close_matches(key, [k for k in params if isinstance(k, str)], n=1)
        if close:
            text += f" (params has no key {key!r}; did you mean {close[0]!r}?)"
    return text


def return_location(fn, params: dict) -> str | None:
    """'file:line' of the `return` that produced a bad value: the call is replayed once on a copy of the
    params with a profile hook (only on this error path); the `def` line when no return is seen."""
    code = getattr(fn, "__code__", None)
    if code is None:
        return None
    line = code.co_firstlineno

    def hook(frame, event, arg):
        nonlocal line
        if event == "return" and frame.f_code is code:
            line = frame.f_lineno

    old = sys.getprofile()
    sys.setprofile(hook)
    try:
        fn(copy.deepcopy(params))
    except Exception:  # noqa: BLE001 - only replaying to find the line
        pass
    finally:
        sys.setprofile(old)
    return f"{code.co_filename}:{line}"


def describe_params(params: dict) -> str:
    """Params on one line each key, with `waypoints` shortened, for error messages."""
    parts = []
    for k, v in params.items():
        if k == "waypoints":
            v = f"[{len(v)} waypoints]"
        elif isinstance(v, float):
            v = round(v, 4)
        parts.append(f"{k}={v}")
    return ", ".join(parts)


class ParamsBuilder:
    """Builds the AWS reward params dicts for a simulator's cars (keys and order: `racerlab.spec.REWARD_PARAMS`)."""

    _make = ParamsMaker(("all_wheels_on_track", "x", "y", "heading", "distance_from_center", "is_left_of_center",
                         "is_reversed", "progress", "steps", "speed", "steering_angle", "waypoints",
                         "closest_waypoints", "track_width", "projection_distance", "is_offtrack"),
                        parts={"closest_waypoints": 2})

    _OBJECT_KEYS = ("closest_objects", "objects_location", "objects_left_of_center", "objects_distance",
                    "objects_distance_from_center", "objects_heading", "objects_speed", "object_in_camera")
    _make_objects = ParamsMaker((*_make.per_row, "is_crashed", *_OBJECT_KEYS),
                                parts={"closest_waypoints": 2, "closest_objects": 2})

    def __init__(self, sim):
        self.sim = sim
        self._waypoints = (sim.track.waypoints, sim.track_reversed.waypoints)
        self._length = sim.track.length
        self._constants = {"track_length": sim.track.length, "is_crashed": False, **NO_OBJECTS}

    def build(self, idx=None, status=None, actions=None) -> list[dict]:
        """Params for cars `idx` (all by default) from `sim.params`, with the commanded actions."""
        return list(self.each(idx, status, actions))

    def each(self, idx=None, status=None, actions=None):
        """Yield the params dict of each car in `idx` in turn (streaming keeps memory warm for big batches)."""
        sim = self.sim
        idx = np.arange(sim.num_cars) if idx is None else np.asarray(idx)
        c = sim.params[idx].T.tolist()  # the judged pose's measurements, one list per K.M* column
        ctr = sim.ctr[idx].T.tolist()
        st = sim.status[idx] if status is None else np.asarray(status)[idx]
        steer = sim.car[idx, K.CCMD_STEER] if actions is None else actions[0][idx]
        speed = sim.car[idx, K.CCMD_SPEED] if actions is None else actions[1][idx]
        rev = [r != 0 for r in ctr[K.KREV]]
        wps = self._waypoints
        cols = {
            "all_wheels_on_track": [w == 4.0 for w in c[K.MWHEELS]],
            "x": c[K.MX],
            "y": c[K.MY],
            "heading": c[K.MHEADING],
            "distance_from_center": c[K.MDIST],
            "is_left_of_center": [v > 0.5 for v in c[K.MLEFT]],
            "is_reversed": rev,
            "progress": c[K.MPROG],
            "steps": [float(v) for v in ctr[K.KSTEPS]],
            "speed": np.asarray(speed, dtype=np.float64).tolist(),
            "steering_angle": np.asarray(steer, dtype=np.float64).tolist(),
            "track_width": c[K.MWIDTH],
            "waypoints": [wps[r] for r in rev],
            "closest_waypoints": ([int(v) for v in c[K.MWP_PREV]], [int(v) for v in c[K.MWP_NEXT]]),
            "projection_distance": c[K.MS],
            "is_offtrack": (st == K.OFF_TRACK).tolist(),
        }
        # sim_time of the measured pose: the step's start (AWS order) or its end (after_action)
        t = sim.time if sim.after_action else sim.time - sim.dt
        if sim.objects is None:
            return self._make(cols, {**self._constants, "sim_time": t})
        p = sim.params[idx]
        base = base_from_model_point(p[:, K.MX], p[:, K.MY], p[:, K.MHEADING])
        cols.update(sim.objects.params_columns(idx, p[:, K.MX:K.MY + 1], p[:, K.MS], base))
        cols["is_crashed"] = (st == K.CRASHED).tolist()
        return self._make_objects(cols, {"track_length": self._length, "sim_time": t})


class RewardCaller:
    """Calls a reward function on params dicts and enforces AWS's validity rule (finite, |r| ≤ 1e5)."""

    def __init__(self, fn: Callable[[dict], float]):
        self.fn = fn
        src = getattr(fn, "__racerlab_source__", None)
        self.source = Path(src) if src else None
        self.name = str(self.source) if self.source else getattr(fn, "__qualname__", repr(fn))

    def __call__(self, params_list, cars=None, keep: list | None = None) -> np.ndarray:
        """Rewards for an iterable of params dicts (`cars` names them in errors); dicts are appended
        to `keep` when given."""
        fn = self.fn
        out = []
        for j, params in enumerate(params_list):
            if keep is not None:
                keep.append(params)
            try:
                r = fn(params)
            except Exception as exc:  # noqa: BLE001 - report the user's error with its params
                car = j if cars is None else int(cars[j])
                where = error_location(exc, self.source) or self.name
                raise RewardFunctionError(
                    f"{where}: {describe_exception(exc, params)} (car {car}, step "
                    f"{params.get('steps')})\n  params: {describe_params(params)}") from exc
            if type(r) is not float:  # fast path for the common case
                r = self._coerce(r, params, j if cars is None else int(cars[j]))
            elif not (-MAX_ABS_REWARD <= r <= MAX_ABS_REWARD):
                self._bad(f"returned {r!r}, which is not finite or beyond ±1e5", params, j)
            out.append(r)
        return np.array(out, dtype=np.float64)

    def _coerce(self, r, params, car) -> float:
        if isinstance(r, bool) or not isinstance(r, numbers.Real):
            self._bad(f"returned {r!r} of type {type(r).__name__}; it must return a number (float)", params, car)
        r = float(r)
        if not math.isfinite(r) or abs(r) > MAX_ABS_REWARD:
            self._bad(f"returned {r!r}, which is not finite or beyond ±1e5", params, car)
        return r

    def _bad(self, what: str, params: dict, car: int):
        where = self._return_location(params)
        raise RewardFunctionError(f"{where}: reward_function {what} (car {car}, step {params.get('steps')})\n"
                                  f"  params: {describe_params(params)}")

    def _return_location(self, params: dict) -> str:
        return return_location(self.fn, params) or self.name
