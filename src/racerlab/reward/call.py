"""Calling a reward function: the one validity rule (`check_value`: a finite number within ±1e5, facts §1) and
the errors a racer sees, naming the file and line and showing the step's params.

`RewardCaller` raises on the first failure (training, the Gymnasium env); `analysis.rescore` collects failures
with the same `check_value` and the same wording instead.
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
from racerlab.reward.load import error_location, load_reward_function

MAX_ABS_REWARD = 1e5


def as_reward_function(value) -> Callable[[dict], float] | None:
    """A callable, a path to a .py file, or None (no reward and no params: the fastest path)."""
    if value is None or callable(value):
        return value
    return load_reward_function(value)


def check_value(r) -> tuple[float, str | None]:
    """`r` as a float and None when AWS accepts it; otherwise NaN (or the float) and what is wrong with it,
    worded to follow "reward_function "."""
    if isinstance(r, bool) or not isinstance(r, numbers.Real):
        return math.nan, f"returned {r!r} of type {type(r).__name__}; it must return a number (float)"
    r = float(r)
    if not math.isfinite(r):
        return r, f"returned {r!r}, which is not finite"
    if abs(r) > MAX_ABS_REWARD:
        return r, f"returned {r!r}, which is beyond ±1e5 (AWS stops the job)"
    return r, None


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


def source_of(fn) -> Path | None:
    """The reward file a loaded function came from (None for a plain callable)."""
    src = getattr(fn, "__racerlab_source__", None)
    return Path(src) if src else None


class RewardCaller:
    """Calls a reward function on params dicts and raises on the first value `check_value` refuses."""

    def __init__(self, fn: Callable[[dict], float]):
        self.fn = fn
        self.source = source_of(fn)
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
            if type(r) is not float or not -MAX_ABS_REWARD <= r <= MAX_ABS_REWARD:  # the common case skips this
                r, what = check_value(r)
                if what is not None:
                    self._bad(what, params, j if cars is None else int(cars[j]))
            out.append(r)
        return np.array(out, dtype=np.float64)

    def _bad(self, what: str, params: dict, car: int):
        where = return_location(self.fn, params) or self.name
        raise RewardFunctionError(f"{where}: reward_function {what} (car {car}, step {params.get('steps')})\n"
                                  f"  params: {describe_params(params)}")


def as_reward_caller(reward) -> RewardCaller | None:
    """A `RewardCaller`, a callable, a path to a reward_function.py, or None (no reward, no params)."""
    if reward is None or isinstance(reward, RewardCaller):
        return reward
    return RewardCaller(as_reward_function(reward))
