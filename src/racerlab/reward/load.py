"""`reward_function.py`: loading a racer's reward function, with one-line errors that name the file and line."""

from __future__ import annotations

import importlib.util
import sys
import traceback
from collections.abc import Callable
from pathlib import Path

from racerlab.errors import RewardFunctionError


def load_reward_function(path) -> Callable[[dict], float]:
    """Import `reward_function` from a .py file; syntax errors and a missing function are one-line errors."""
    p = Path(path)
    if not p.is_file():
        raise RewardFunctionError(f"{p}: reward function file not found")
    name = f"racerlab_reward_{abs(hash(str(p.resolve())))}"
    spec = importlib.util.spec_from_file_location(name, p)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except SyntaxError as exc:
        raise RewardFunctionError(f"{p}:{exc.lineno}: syntax error: {exc.msg}") from None
    except Exception as exc:  # noqa: BLE001 - the user's module failed to import
        where = error_location(exc, p) or str(p)
        raise RewardFunctionError(f"{where}: importing the reward function raised "
                                  f"{type(exc).__name__}: {exc}") from None
    fn = getattr(module, "reward_function", None)
    if not callable(fn):
        raise RewardFunctionError(f"{p}: defines no function `reward_function(params)`; "
                                  "add `def reward_function(params): ... return float(reward)`")
    fn.__racerlab_source__ = str(p)
    sys.modules.pop(name, None)
    return fn


def error_location(exc: BaseException, path: Path | None) -> str | None:
    """'file:line' of the deepest traceback frame inside the reward file (or the deepest frame)."""
    frames = traceback.extract_tb(exc.__traceback__)
    if not frames:
        return None
    if path is not None:
        target = str(Path(path).resolve())
        mine = [f for f in frames if str(Path(f.filename).resolve()) == target]
        if mine:
            return f"{mine[-1].filename}:{mine[-1].lineno}"
    f = frames[-1]
    return f"{f.filename}:{f.lineno}"
