"""`calibrate(paths, ...)`: the whole calibration of `racerlab calibrate`, and the `[car]` table it writes."""

from __future__ import annotations

import math
import os
import stat
import tarfile
import zlib

import numpy as np

from racerlab.analysis import load
from racerlab.calibrate.data import HORIZON, Stretches, concat, split, stretches
from racerlab.calibrate.fit import Fit, fit_with_spread, fitted_rows, search_bounds
from racerlab.errors import ConfigError, RacerlabError
from racerlab.sim.car import log_timing
from racerlab.spec import DEFAULT_SIMULATOR, car_params

MAX_STRETCHES = 2500  # per log, by default: stretches overlap, more mostly cost time
MIN_STRETCHES = 150  # fewer (about 10 s of driving) cannot pin nine constants down
MAX_RESAMPLES = 50  # each is one more fit (seconds to minutes); the spread settles long before


def load_stretches(paths, every: int | None = None, timing: str = "previous") -> Stretches:
    """The stretches of every log in `paths` (each a folder, export or robomaker log `racerlab.analysis.load` reads),
    one starting at every `every`-th row (default: about MAX_STRETCHES per log); episodes of different logs stay
    apart."""
    for p in paths:
        check_log_path(p)
    parts = []
    offset = 0
    for p in paths:
        df = _read(p)
        st = stretches(df, every=every or max(1, len(df) // MAX_STRETCHES), source=str(p), timing=timing)
        _check_finite(st, p)
        st.episode = st.episode + offset
        offset = int(st.episode.max()) + 1
        parts.append(st)
    return concat(parts)


def check_log_path(p) -> None:
    """A log path calibrate can read: a folder or a regular file (not a FIFO or a device it would read for ever),
    followed through symlinks; one line naming it otherwise."""
    try:
        mode = os.stat(p).st_mode
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such file or folder; give a simtrace folder, a console/DRoA export or a "
                          "robomaker log") from None
    except OSError as exc:  # a symlink loop, a folder it may not enter
        raise ConfigError(f"{p}: cannot be opened ({exc.strerror}); give a simtrace folder, a console/DRoA export "
                          "or a robomaker log") from None
    if not (stat.S_ISDIR(mode) or stat.S_ISREG(mode)):
        raise ConfigError(f"{p}: not a file or a folder (a pipe or a device); give a simtrace folder, a console/DRoA "
                          "export or a robomaker log saved to a file")


def _read(p):
    """`analysis.load` of one log, a damaged one (a cut archive, a repeated column, numbers out of range, a link
    loop inside a folder) as one line naming it."""
    try:
        return load(p)
    except RacerlabError:
        raise
    except (OSError, EOFError, ValueError, KeyError, tarfile.TarError, zlib.error) as exc:
        why = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"{p}: cannot be read as a log ({why[:200]}); check the file (a complete download, one "
                          "header row) or give another log") from None


def _check_finite(st: Stretches, p) -> None:
    bad = ~(np.isfinite(st.commands).all(axis=(1, 2)) & np.isfinite(st.target).all(axis=(1, 2))
            & np.isfinite(st.start[:, [0, 1, 2, 3, 5]]).all(axis=1) & np.isfinite(st.dts).all(axis=1))
    if bad.any():
        raise ConfigError(f"{p}: {int(bad.sum())} of {len(st)} stretches hold values that are not finite numbers "
                          "(inf or NaN in x, y, heading, steering or speed); a fit on them is meaningless: give a "
                          "log without them")


def check_resamples(resamples: int) -> None:
    if not 0 <= resamples <= MAX_RESAMPLES:
        raise ConfigError(f"--resamples {resamples}: give 0 to {MAX_RESAMPLES} (each resample is one more fit; 3 "
                          "give the spread of the constants)")


def calibrate(paths, simulator: str = DEFAULT_SIMULATOR, version="5", *, every: int | None = None, resamples: int = 3,
              seed: int = 0) -> Fit:
    """Fit `simulator`'s car for a `version` model to the logs at `paths`: every third episode is held out and
    reported on (the `Fit` keeps those stretches in `held`). Logs too short to pin the car down, with
    non-finite values, or damaged, and more than MAX_RESAMPLES resamples are refused before the fit."""
    check_resamples(resamples)
    st = load_stretches(paths, every, log_timing(car_params(simulator, version)))
    if len(st) < MIN_STRETCHES:
        names = ", ".join(str(p) for p in paths)
        raise ConfigError(f"{names}: only {len(st)} stretches of {HORIZON} driven steps to fit (at least "
                          f"{MIN_STRETCHES}, about {MIN_STRETCHES // 15 + 2} s of driving, pin the car down); give "
                          "longer logs")
    fit_st, held_st = split(st)
    return fit_with_spread(fit_st, held_st, simulator, version, resamples=resamples, seed=seed)


def on_bounds(fit: Fit) -> list[str]:
    """The fitted constants that sit on the edge of their search range (a lower edge of 0, no lag, is an answer):
    the logs did not pin them down."""
    out = []
    for name, (lo, hi) in search_bounds(fit.car.TABLE).items():
        value = getattr(fit.car, name, None)
        if value is None:  # a constant searched as its inverse ("1/slide_mps"): 0 (none) and the fastest are edges
            continue
        edges = [hi] if lo == 0 else [lo, hi]  # 0 is a real answer for a lag or a delay: none
        if min(abs(value - e) for e in edges) <= 1e-3 * (hi - lo):
            out.append(f"{name} = {value:.4g} sits on the edge of its search range [{lo:g}, {hi:g}]: the logs do "
                       "not pin it down; give logs that exercise it (harder braking, faster turns)")
    return out


def _interval_note(fit: Fit) -> str:
    """The held-out figure's 90 % interval over resampled episodes, for the table's comment; with too few episodes
    to resample (`fit.median_interval`), how many were held out."""
    lo, hi = fit.held_out_interval
    if not math.isfinite(lo):
        return f"; {fit.held_out_episodes} held-out episode{'' if fit.held_out_episodes == 1 else 's'}"
    return f"; after {list(fit.held_out)[-1]} steps {lo:.3f}-{hi:.3f} over {fit.held_out_episodes} resampled episodes"


def car_toml(fit: Fit, source: str = "") -> str:
    """The `[car]` table of a fit, to paste into training.toml."""
    lines = ["# racerlab calibrate" + (f": {source}" if source else ""),
             f"# held-out median front-point error (m) after {', '.join(f'{h}' for h in fit.held_out)} steps: "
             + ", ".join(f"{v:.3f}" for v in fit.held_out.values())
             + " (constant velocity: " + ", ".join(f"{v:.3f}" for v in fit.constant_velocity.values()) + ")"
             + _interval_note(fit),
             "[car]", f'simulator = "{fit.car.simulator}"']
    for name in (c.name for c in fitted_rows(fit.car.TABLE)):
        spread = fit.spread.get(name, math.nan)
        note = f"  # ± {spread:.3g}" if math.isfinite(spread) else ""
        lines.append(f"{name} = {getattr(fit.car, name):.4g}{note}")
    return "\n".join(lines) + "\n"
