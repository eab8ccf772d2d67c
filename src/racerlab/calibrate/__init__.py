"""Calibrating racerlab's car against a real simulator's logs (`racerlab calibrate`, docs/car.md).

Reads simtraces through `racerlab.analysis.load` (any folder, export or robomaker log it reads), cuts them
into stretches (`data`), fits the car's constants (`fit`) on part of the episodes and measures on the rest
how far the fitted car's front point lands from the logged one, beside the constant-velocity guess.
"""

from racerlab.calibrate.data import HORIZON, Stretches, split, stretches
from racerlab.calibrate.fit import (
                                    FITTED,
                                    HORIZONS,
                                    Fit,
                                    constant_velocity_errors,
                                    errors,
                                    fit_car,
                                    fit_with_spread,
                                    learned_floor,
                                    median_interval,
                                    medians,
)
from racerlab.calibrate.run import calibrate, car_toml, load_stretches

__all__ = ["FITTED", "HORIZON", "HORIZONS", "Fit", "Stretches", "calibrate", "car_toml", "constant_velocity_errors",
           "errors", "fit_car", "learned_floor", "load_stretches", "median_interval",
           "fit_with_spread", "medians", "split", "stretches"]
