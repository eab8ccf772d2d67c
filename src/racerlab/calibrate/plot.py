"""The calibration's picture: replayed against logged paths, the fitted car's step responses, error by horizon."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from racerlab.calibrate.fit import Fit, constant_velocity_errors, errors, predict
from racerlab.calibrate.out import PNG_MARK
from racerlab.logs import atomic_write_bytes
from racerlab.sim.car import rollout
from racerlab.spec import STEP_S, CarParams


def step_responses(car: CarParams, steps: int = 20) -> dict[str, np.ndarray]:
    """The car's answer to a steering step (0 -> 20° at 1 m/s: heading, °) and a speed step (1 -> 2 m/s: ground
    speed from the front point's motion), each command given at step 0 after a long hold of the one before."""
    hold = [[0.0, 1.0]] * 6
    start = {"x": 0.0, "y": 0.0, "heading": 0.0, "speed": car.ground_factor, "steering_angle": 0.0}
    turn = rollout(start, [[20.0, 1.0]] * steps, history=hold, car=car)
    fast = rollout(start, [[0.0, 2.0]] * steps, history=hold, car=car)
    xs = np.concatenate([[0.0], fast[:, 0]])
    return {"t": STEP_S * np.arange(1, steps + 1), "heading_deg": turn[:, 2], "speed_mps": np.diff(xs) / STEP_S}


def plot_fit(fit: Fit, path, *, examples: int = 40, seed: int = 0) -> Path:
    """Write the picture of `fit` (its held-out stretches) to `path` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    held = fit.held
    fig, ax = plt.subplots(1, 3, figsize=(16, 5.2))
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(held), size=min(examples, len(held)), replace=False)
    pred = predict(held.take(pick), fit.car)
    for k, i in enumerate(pick):
        logged = np.vstack([held.start[i, :2], held.target[i, :, :2]])
        guess = np.vstack([held.start[i, :2], pred[k, :, :2]])
        ax[0].plot(logged[:, 0], logged[:, 1], "k-", lw=1.2, label="logged" if k == 0 else None)
        ax[0].plot(guess[:, 0], guess[:, 1], "-", color="tab:red", lw=1, label="fitted car" if k == 0 else None)
    ax[0].set_aspect("equal")
    ax[0].set_title(f"{len(pick)} held-out stretches of 1 s: front point")
    ax[0].legend(loc="best")
    r = step_responses(fit.car)
    ax[1].plot(r["t"], r["speed_mps"], "o-", color="tab:blue", label="speed m/s (1 → 2 m/s command)")
    ax1b = ax[1].twinx()
    ax1b.plot(r["t"], r["heading_deg"], "s-", color="tab:green", label="heading ° (0 → 20° steering at 1 m/s)")
    ax[1].set_xlabel("s after the command's row")
    ax[1].set_ylabel("ground speed (m/s)")
    ax1b.set_ylabel("heading (°)")
    ax[1].set_title("fitted car's step responses")
    ax[1].legend(loc="upper left")
    ax1b.legend(loc="lower right")
    h = np.arange(1, held.dts.shape[1] + 1)
    ax[2].plot(h, np.median(errors(held, fit.car), axis=0), "o-", color="tab:red", label="fitted car")
    ax[2].plot(h, np.median(constant_velocity_errors(held), axis=0), "s--", color="gray", label="constant velocity")
    ax[2].set_xlabel("steps after the start")
    ax[2].set_ylabel("median front-point error (m)")
    ax[2].set_title(f"held out: {fit.held_out_stretches} stretches")
    ax[2].legend()
    ax[2].grid(alpha=0.3)
    fig.suptitle(f"racerlab calibrate: {fit.car.name}")
    fig.tight_layout()
    buf = io.BytesIO()  # the Software text marks the picture as this command's (it may redraw it, nothing else)
    fig.savefig(buf, dpi=90, format="png", metadata={"Software": PNG_MARK.decode()})
    plt.close(fig)
    return atomic_write_bytes(path, buf.getvalue())
