"""`calibrate(paths, ...)`: the whole calibration of `racerlab calibrate`, and the `[car]` table it writes."""

from __future__ import annotations

import math
from pathlib import Path

from racerlab.analysis import load
from racerlab.calibrate.data import Stretches, concat, split, stretches
from racerlab.calibrate.fit import FITTED, Fit, fit_with_spread
from racerlab.errors import ConfigError
from racerlab.sim.car import log_timing
from racerlab.spec import DEFAULT_SIMULATOR, car_params

MAX_STRETCHES = 2500  # per log, by default: stretches overlap, more mostly cost time


def load_stretches(paths, every: int | None = None, timing: str = "previous") -> Stretches:
    """The stretches of every log in `paths` (each a folder, export or robomaker log `racerlab.analysis.load` reads),
    one starting at every `every`-th row (default: about MAX_STRETCHES per log), steps timed by the rule `timing`
    (`racerlab.sim.car.log_timing`); episodes of different logs stay apart."""
    parts = []
    offset = 0
    for p in paths:
        if not Path(p).exists():
            raise ConfigError(f"{p}: no such file or folder; give a simtrace folder, a console/DRoA export or a "
                              "robomaker log")
        df = load(p)
        st = stretches(df, every=every or max(1, len(df) // MAX_STRETCHES), source=str(p), timing=timing)
        st.episode = st.episode + offset
        offset = int(st.episode.max()) + 1
        parts.append(st)
    return concat(parts)


def calibrate(paths, simulator: str = DEFAULT_SIMULATOR, version="5", *, every: int | None = None, resamples: int = 3,
              seed: int = 0) -> Fit:
    """Fit `simulator`'s car for a `version` model to the logs at `paths`: every third episode is held out and
    reported on (the `Fit` keeps those stretches in `held`)."""
    timing = log_timing(car_params(simulator, version))
    fit_st, held_st = split(load_stretches(paths, every, timing))
    return fit_with_spread(fit_st, held_st, simulator, version, resamples=resamples, seed=seed)


def car_toml(fit: Fit, source: str = "") -> str:
    """The `[car]` table of a fit, to paste into training.toml."""
    lines = ["# racerlab calibrate" + (f": {source}" if source else ""),
             f"# held-out median front-point error (m) after {', '.join(f'{h}' for h in fit.held_out)} steps: "
             + ", ".join(f"{v:.3f}" for v in fit.held_out.values())
             + " (constant velocity: " + ", ".join(f"{v:.3f}" for v in fit.constant_velocity.values()) + ")",
             "[car]", f'simulator = "{fit.car.simulator}"']
    for name in FITTED:
        spread = fit.spread.get(name, math.nan)
        note = f"  # ± {spread:.3g}" if math.isfinite(spread) else ""
        lines.append(f"{name} = {getattr(fit.car, name):.4g}{note}")
    return "\n".join(lines) + "\n"
