"""A learned floor for the fitted car: how much of its error a regression on top of it removes, inside one log.

The fitted car's prediction of each stretch is corrected by a ridge regression learned on the fit stretches of
the same log: from the start's speed and yaw rate, the history's and the replayed commands and the car's own
prediction, it guesses where the logged front point lies from the predicted one (in the start's heading frame),
after each horizon. Its held-out error is what a model of this log's motions could still gain over the physics
car; beside the constant-velocity guess it tells a racer how far to trust the fitted car.
"""

from __future__ import annotations

import numpy as np

from racerlab.calibrate.data import Stretches

RIDGE = 1e-2  # the regression's penalty on standardised features


def _features(st: Stretches, pred: np.ndarray, h: int) -> np.ndarray:
    """(N, F) what the regression sees for the horizon `h`: the start, the commands, the car's own prediction
    (in the start's frame) and their products with the speed."""
    yaw = st.start[:, 2]
    c, s = np.cos(yaw), np.sin(yaw)
    dx, dy = pred[:, h - 1, 0] - st.start[:, 0], pred[:, h - 1, 1] - st.start[:, 1]
    along, across = c * dx + s * dy, -s * dx + c * dy
    turn = np.radians((pred[:, h - 1, 2] - np.degrees(yaw) + 180.0) % 360.0 - 180.0)
    v = st.start[:, 3:4]
    cmds = st.commands.reshape(len(st), -1)
    base = np.column_stack([v, st.start[:, 5:6], cmds, along, across, turn])
    return np.column_stack([base, base * v, np.ones(len(st))])


def _frame_residual(st: Stretches, pred: np.ndarray, h: int) -> np.ndarray:
    """(N, 2) the logged front point minus the predicted one after `h` steps, in the start's heading frame."""
    yaw = st.start[:, 2]
    c, s = np.cos(yaw), np.sin(yaw)
    ex, ey = st.target[:, h - 1, 0] - pred[:, h - 1, 0], st.target[:, h - 1, 1] - pred[:, h - 1, 1]
    return np.column_stack([c * ex + s * ey, -s * ex + c * ey])


def _ridge(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ridge coefficients on standardised features: (mean, scale, coefficients)."""
    mu, sd = x.mean(axis=0), x.std(axis=0)
    sd[sd < 1e-12] = 1.0
    mu[-1], sd[-1] = 0.0, 1.0  # the constant column stays a constant
    z = (x - mu) / sd
    coef = np.linalg.solve(z.T @ z + RIDGE * len(z) * np.eye(z.shape[1]), z.T @ y)
    return mu, sd, coef


def floor_errors(fit_st: Stretches, held_st: Stretches, p_fit: np.ndarray, p_held: np.ndarray,
                 horizons) -> np.ndarray:
    """(N, max horizon) held-out errors (m; filled at each of `horizons` steps, NaN elsewhere) of the car's
    predictions `p_held` corrected by a regression learned on `fit_st` and its predictions `p_fit` (the same log's
    fit episodes)."""
    out = np.full((len(held_st), max(horizons)), np.nan)
    for h in horizons:
        mu, sd, coef = _ridge(_features(fit_st, p_fit, h), _frame_residual(fit_st, p_fit, h))
        corr = ((_features(held_st, p_held, h) - mu) / sd) @ coef
        out[:, h - 1] = np.hypot(*(_frame_residual(held_st, p_held, h) - corr).T)
    return out
