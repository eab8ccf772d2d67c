"""Watchdogs of a training run: a reward call that runs past its time budget stops training (with the
reward file's line, the params and the time), a slow reward is reported once with its cost per call.

The budget is a real-time interval timer (SIGALRM) armed around each call, so an endless loop in
reward_function.py is interrupted where it is; the error then goes through the reward caller's usual
report (file:line, params). Only the main thread can take signals: elsewhere calls are timed, not cut.
"""

from __future__ import annotations

import signal
import threading
import time

SLOW_CALL_S = 0.005  # a reward slower than 5 ms a call costs more than the simulator: say so once
SLOW_AFTER_CALLS = 50


class RewardTimeout(Exception):  # noqa: N818 - reported to the user as what happened
    """Raised inside the reward function when a call runs past the budget."""


class RewardWatchdog:
    """Wraps the user's reward function: times each call, cuts one that runs past `budget_s`."""

    def __init__(self, fn, budget_s: float, note=None):
        self.fn = fn
        self.budget_s = float(budget_s)
        self.note = note or (lambda text: None)
        self.__racerlab_source__ = getattr(fn, "__racerlab_source__", None)
        self.__qualname__ = getattr(fn, "__qualname__", "reward_function")
        self.calls = 0
        self.seconds = 0.0
        self.warned = False
        self.armed = False
        self._previous = None

    def __enter__(self) -> RewardWatchdog:
        if self.budget_s > 0 and threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGALRM, self._expired)
            self.armed = True
        return self

    def __exit__(self, *exc) -> None:
        if self.armed:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, self._previous)
            self.armed = False

    def _expired(self, signum, frame):
        raise RewardTimeout(f"took longer than the reward time budget of {self.budget_s:g} s (an endless loop?); "
                            "fix the function, or raise run.reward_budget_s in training.toml")

    def __call__(self, params):
        t0 = time.perf_counter()
        if self.armed:
            signal.setitimer(signal.ITIMER_REAL, self.budget_s)
        try:
            return self.fn(params)
        finally:
            if self.armed:
                signal.setitimer(signal.ITIMER_REAL, 0)
            self._count(time.perf_counter() - t0)

    def _count(self, dt: float) -> None:
        self.calls += 1
        self.seconds += dt
        if not self.warned and self.calls >= SLOW_AFTER_CALLS and self.seconds > SLOW_CALL_S * self.calls:
            self.warned = True
            per_call = self.seconds / self.calls
            self.note(f"{self.__racerlab_source__ or self.__qualname__}: the reward function is slow, "
                      f"{per_call * 1000:.1f} ms a call over {self.calls} calls ({1 / per_call:.0f} steps/s at "
                      "most); training waits for it")
