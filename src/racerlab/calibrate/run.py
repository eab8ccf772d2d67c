"""`calibrate(paths, ...)`: the whole calibration of `racerlab calibrate`, and the `[car]` table it writes."""

from __future__ import annotations

import math
import os
import tarfile
import warnings
import zlib
from dataclasses import replace

import numpy as np

from racerlab.analysis import load
from racerlab.calibrate.data import HORIZON, Stretches, concat, drop_copies, split, stretches
from racerlab.calibrate.fit import (
    FITTED,
    INVERSE,
    Fit,
    errors,
    fit_with_spread,
    fitted_rows,
    learned_floor,
    median_interval,
    medians,
    search_bounds,
)
from racerlab.errors import ConfigError, RacerlabError, RacerlabWarning
from racerlab.logs.files import check_path
from racerlab.sim.car import log_timing
from racerlab.spec import DEFAULT_SIMULATOR, car_params, implausible

MAX_STRETCHES = 2500  # per log, by default: stretches overlap, more mostly cost time
MIN_STRETCHES = 150  # fewer (about 10 s of driving) cannot pin nine constants down
MAX_RESAMPLES = 50  # each is one more fit (seconds to minutes); the spread settles long before
MAX_VERSION = 6  # model_metadata versions AWS's simulators have used: 1 to 6 (DRoA's)


def load_stretches(paths, every: int | None = None, timing: str = "previous") -> Stretches:
    """The stretches of every log in `paths` (each a folder, export or robomaker log `racerlab.analysis.load` reads),
    one starting at every `every`-th row (default: about MAX_STRETCHES per log); episodes of different logs stay
    apart. A log given twice (or inside a folder also given) is refused; an episode that repeats another row for row
    is left out, with one warning saying so (`data.drop_copies`)."""
    for p in paths:
        check_log_path(p)
    check_distinct(paths)
    parts, seen, copies = [], {}, []
    offset = 0
    for p in paths:
        df, notes = drop_copies(_read(p), seen, str(p))
        copies += notes
        if notes and df.empty:
            continue  # the whole log repeats the ones before it
        st = stretches(df, every=every or max(1, len(df) // MAX_STRETCHES), source=str(p), timing=timing)
        _check_finite(st, p)
        st.episode = st.episode + offset
        offset = int(st.episode.max()) + 1
        parts.append(st)
    if copies:
        more = f" and {len(copies) - 1} more" if len(copies) > 1 else ""
        warnings.warn(f"left out {len(copies)} episode{'' if len(copies) == 1 else 's'} that repeat another row for "
                      f"row ({copies[0]}{more}): a copy is no second drive", RacerlabWarning, stacklevel=2)
    return concat(parts)


def check_log_path(p) -> None:
    """A log path calibrate can read: a folder or a regular file (not a FIFO or a device it would read for ever),
    followed through symlinks; one line naming it otherwise (`logs.files.check_path`, the check every log reader
    makes)."""
    check_path(p, "a simtrace folder, a console/DRoA export or a robomaker log saved to a file")


def check_distinct(paths) -> None:
    """Each log once: the same file or folder given twice, or a log inside a folder also given, would count its
    episodes twice (fitted beside themselves, or held out against their own copies)."""
    real = [os.path.realpath(p) for p in paths]
    for i, a in enumerate(real):
        for j, b in enumerate(real):
            if i == j or not (b == a and j > i or b.startswith(a.rstrip(os.sep) + os.sep)):
                continue
            how = "is the same log as" if a == b else "lies inside"
            raise ConfigError(f"{paths[j]}: {how} {paths[i]}, also given: its episodes would count twice; give "
                              "each log once")


def check_version(version) -> str:
    """The model_metadata `version` of the logged model, as the car takes it: a number from 1 to MAX_VERSION."""
    try:
        v = float(str(version).strip())
    except ValueError:
        v = math.nan
    if not (1 <= v <= MAX_VERSION):
        raise ConfigError(f"--version {version}: give the logged model's model_metadata.json version, 1 to "
                          f"{MAX_VERSION} (3-4: effort control, 5 and on: velocity control)")
    return str(version).strip()


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
              seed: int = 0, say=None) -> Fit:
    """Fit `simulator`'s car for a `version` model to the logs at `paths`: every third episode is held out and
    reported on (the `Fit` keeps those stretches in `held`). Logs too short to pin the car down, with non-finite
    values, damaged, given twice or of one episode, a version that is no model's, and more than MAX_RESAMPLES
    resamples are refused before the fit; `say(text)` hears when the fit (minutes) starts. The car it returns holds
    only values training accepts (`plausible`)."""
    check_resamples(resamples)
    version = check_version(version)
    st = load_stretches(paths, every, log_timing(car_params(simulator, version)))
    names = ", ".join(str(p) for p in paths)
    if len(st) < MIN_STRETCHES:
        raise ConfigError(f"{names}: only {len(st)} stretches of {HORIZON} driven steps to fit (at least "
                          f"{MIN_STRETCHES}, about {MIN_STRETCHES // 15 + 2} s of driving, pin the car down); give "
                          "longer logs")
    fit_st, held_st = split(st, source=names)
    if say is not None:
        say(f"fitting the {simulator} car (version {version}) to {len(fit_st)} stretches of "
            f"{len(np.unique(fit_st.episode))} episodes of {names} ...")
    fit = fit_with_spread(fit_st, held_st, simulator, version, resamples=resamples, seed=seed)
    return plausible(fit, fit_st, held_st)


def plausible(fit: Fit, fit_st: Stretches, held_st: Stretches) -> Fit:
    """`fit` with every constant one a `[car]` table may hold (`spec.CAR_PLAUSIBLE`, what training accepts). A slide,
    fade or saturation is searched as its inverse, so a fit that finds none of it lands on a huge value (a fade at
    761 m/s): that is written as 0, none, and the held-out figures are measured again on the car written; one
    warning says so. Any other constant out of range is one line, for the logs did not pin the car down."""
    off, notes = {}, []
    for name in FITTED:
        value = getattr(fit.car, name)
        why = implausible(name, value)
        if why is None:
            continue
        if name in INVERSE.values() and value > 0:
            off[name] = 0.0
            notes.append(f"{name} {value:.4g}")
            continue
        raise ConfigError(f"the fit gives {name} = {value:.4g}, which training refuses ({why}): the logs do not pin "
                          "the car down; give longer logs of harder driving")
    if not off:
        return fit
    warnings.warn(f"the fit found no {', '.join(n for n in off)} in the logs ({', '.join(notes)}, past what a "
                  "DeepRacer car has): written as 0, none", RacerlabWarning, stacklevel=3)
    car = replace(fit.car, **off)
    err = errors(held_st, car)
    return replace(fit, car=car, spread={**fit.spread, **{n: math.nan for n in off}}, held_out=medians(err),
                   floor=learned_floor(fit_st, held_st, car),
                   held_out_interval=median_interval(err[:, -1], held_st.episode))


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
