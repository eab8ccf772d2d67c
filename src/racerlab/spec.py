"""What racerlab takes from AWS DeepRacer, defined once: step time, the car, episode statuses, reward params.

Every other part reads these names from here (a leaf module: it imports nothing from racerlab but
`errors`), so the simulator, the racing line, training, evaluation and log analysis cannot drift apart.

- Time: one environment step is one camera frame at 15 Hz of simulated time (facts §2).
- The car (facts §3): wheelbase, wheel track, the steering clip and the commanded-speed clip that the
  simulator applies, and the point 0.14 m ahead of the base where AWS measures positions; racerlab's dynamic
  constants (lags, gains, traction limits), modelled in `racerlab.sim.car`. `CAR_CONSTANTS` is the one table of
  them all (default, unit, valid and plausible values, "off" value, packing for the compiled step, randomisation,
  the fit's search range), from which `CarParams`' fields and validation, `CAR_PLAUSIBLE`, `sim.car`'s packed
  order and `RANDOMISED` and `calibrate.fit`'s lists are derived; `CAR_TABLE` holds the fitted cars.
- Episode statuses: the simtrace's `episode_status` strings (in the simulator's code order) and the labels
  of the metrics JSON (facts §7).
- Races (next_capabilities §A): `RaceConfig`, a race's settings with DRfC's names and defaults (object
  avoidance boxes, bot cars, the crash penalty), read from the `[race]` table of training.toml.
- Reward params: `REWARD_PARAMS`, the 27 keys of the AWS params dict in AWS order with type, unit and
  meaning (facts §1), and `ParamsMaker`, the one place that turns columns of values into those dicts.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from racerlab.errors import ConfigError

# ---- time -------------------------------------------------------------------------------------------------
STEPS_PER_SECOND = 15
STEP_S = 1.0 / STEPS_PER_SECOND  # one environment step: one camera frame at 15 Hz of simulated time

# ---- the car ----------------------------------------------------------------------------------------------
MIN_SPEED = 0.1  # m/s: commanded speeds are clipped to [MIN_SPEED, MAX_SPEED] when the car is driven
MAX_SPEED = 4.0
MAX_STEERING_DEG = 30.0  # both front wheels are steered by the commanded angle clipped to ±30°
WHEELBASE_M = 0.164
WHEEL_TRACK_M = 0.16
MODEL_POINT_AHEAD_M = 0.14  # AWS RELATIVE_POSITION_OF_FRONT_OF_CAR: x, y, progress, ... are measured here


# DeepRacer on AWS / DRfC >= 6 (simapp 6.x, ROS 2); the AWS console / DRfC <= 5 (simapp <= 5.3, ROS 1)
SIMULATORS = ("droa", "console")
DEFAULT_SIMULATOR = "droa"
CONTROLS = ("velocity", "effort")  # model_metadata version >= 5 | 3-4 (facts §3)
MAX_DELAY_STEPS = 3.0  # the compiled step keeps this many past commands (plus one)
WHEEL_CAP_MPS = 3.5  # 100 rad/s (URDF wheel velocity limit) x 0.035 m (the controller's wheel radius)
MAX_SUBSTEPS = 64  # bounds the compiled step's inner loop for everyone (a [car] table's `substeps`)


class Range(NamedTuple):
    """The values from `low` to `high`, `low` itself left out when `above` (a CarParams constant's domain)."""

    low: float = -math.inf
    high: float = math.inf
    above: bool = False

    def holds(self, value) -> bool:
        """`value` is in the range (NaN never is)."""
        return (value > self.low if self.above else value >= self.low) and value <= self.high

    def words(self) -> str:
        """The range as an error message says it: "> 0", ">= 0", "in [0, 3]"."""
        if self.high == math.inf:
            return f"{'>' if self.above else '>='} {self.low:g}"
        return f"in [{self.low:g}, {self.high:g}]"


POSITIVE = Range(0.0, above=True)
NON_NEGATIVE = Range(0.0)


class Search(NamedTuple):
    """Where `racerlab calibrate` searches a constant: from `low` to `high`, of the constant itself or, `inverse`, of
    1 / constant (0 = off: a slide or a fade speed of infinity), and, `only_if_on`, only for a car that has the term
    (on logs without it the extra freedom only lets the other constants wander)."""

    low: float
    high: float
    inverse: bool = False
    only_if_on: bool = False


class CarConstant(NamedTuple):
    """One of the car's constants, a field of `CarParams`, and everything racerlab does with it.

    `valid`: what CarParams takes (tests build extreme cars); `choices`: the same for a name; `plausible`: what a
    user's [car] table may set, (low, high) in `unit` (`implausible`); `off`: the value that switches its term off
    (randomised draws and the fit keep it off); `packed`: how the compiled step reads it (`sim.car.pack`: "value",
    "radians"; "" not at all), its position being its place among the packed rows; `randomised`: None when
    randomised dynamics leave it alone, else the least a draw may go (`sim.car.randomised`, within the fit's spread
    `CAR_SPREAD`); `fit`: where `racerlab calibrate` searches it (`calibrate.fit`), None when it is not fitted.
    """

    name: str
    default: float | int | bool | str
    unit: str
    meaning: str
    valid: Range | None = None
    choices: tuple[str, ...] = ()
    plausible: tuple[float, float] | None = None
    off: float | None = None
    packed: str = ""
    randomised: float | None = None
    fit: Search | None = None


# The car's constants in CarParams' order (the fit searches them in this order too). A new car term is one row here,
# its dynamics in `sim.car` and its fitted values in CAR_TABLE (docs/car.md). The packed positions are compiled into
# the simulator's numba kernels, so racerlab's cache of compiled kernels is keyed on this file too.
CAR_CONSTANTS = (
    # geometry and the command clips (facts §3)
    CarConstant("wheelbase_m", WHEELBASE_M, "m", "between the axles", POSITIVE, plausible=(0.05, 1.0),
                packed="value"),
    CarConstant("track_m", WHEEL_TRACK_M, "m", "between the left and the right wheels", POSITIVE,
                plausible=(0.05, 1.0)),
    CarConstant("max_steer_deg", MAX_STEERING_DEG, "degrees", "both front wheels: the command clipped to ± this",
                POSITIVE, plausible=(5.0, 60.0), packed="radians"),
    CarConstant("min_speed_mps", MIN_SPEED, "m/s", "commanded speeds are clipped to at least this", NON_NEGATIVE,
                plausible=(0.0, 10.0), packed="value"),
    CarConstant("max_speed_mps", MAX_SPEED, "m/s", "the command clip; the wheels' own cap is `wheel_cap_mps`",
                POSITIVE, plausible=(0.1, 10.0), packed="value"),
    # which car
    CarConstant("simulator", DEFAULT_SIMULATOR, "", "droa: DeepRacer on AWS, DRfC >= 6; console: DRfC <= 5",
                choices=SIMULATORS),
    CarConstant("control", "velocity", "", "velocity (model version >= 5) or effort (3-4)", choices=CONTROLS),
    # the fitted dynamics (`sim.car` says what each does); the defaults are the droa velocity car fitted on the
    # DRoA 2026 logs (issue 34: steps timed by DRoA's rule)
    CarConstant("delay_steps", 0.538, "steps", "the action starts to act this many steps after its row (a fraction: "
                "within the step)", Range(0.0, MAX_DELAY_STEPS), plausible=(0.0, MAX_DELAY_STEPS), packed="value",
                randomised=0.0, fit=Search(0.0, 3.0)),
    CarConstant("steer_tau_s", 0.161, "s", "the hinge's first-order lag (the simapp's ROS 2 controller: 0.167 s)",
                NON_NEGATIVE, plausible=(0.0, 2.0), packed="value", randomised=0.0, fit=Search(0.0, 1.0)),
    CarConstant("yaw_gain", 0.638, "", "yaw rate / the kinematic bicycle's at low speed", POSITIVE,
                plausible=(0.05, 5.0), packed="value", randomised=0.05, fit=Search(0.15, 1.2)),
    CarConstant("slide_mps", 0.0, "m/s", "the gain halves at this speed (gain / (1 + (v / slide)²))", NON_NEGATIVE,
                plausible=(0.0, 100.0), off=0.0, packed="value", randomised=0.0, fit=Search(0.0, 2.5, inverse=True)),
    CarConstant("yaw_tau_s", 0.014, "s", "first-order lag of the yaw rate toward the one the wheels ask for (body "
                "inertia, slip)", NON_NEGATIVE, plausible=(0.0, 2.0), packed="value", randomised=0.0,
                fit=Search(0.0, 0.5)),
    CarConstant("speed_tau_s", 0.0089, "s", "first-order lag of the ground speed toward the target", NON_NEGATIVE,
                plausible=(0.0, 5.0), packed="value", randomised=0.0, fit=Search(0.0, 1.0)),
    CarConstant("accel_mps2", 14.9, "m/s²", "traction limit speeding up", POSITIVE, plausible=(0.1, 200.0),
                packed="value", randomised=0.1, fit=Search(0.5, 30.0)),
    CarConstant("brake_mps2", 13.0, "m/s²", "traction limit slowing down", POSITIVE, plausible=(0.1, 200.0),
                packed="value", randomised=0.1, fit=Search(0.5, 30.0)),
    CarConstant("ground_factor", 1.0135, "", "ground speed / command (wheel mesh radius ~0.036 m against the "
                "controller's 0.035)", POSITIVE, plausible=(0.5, 2.0), packed="value", randomised=0.5,
                fit=Search(0.95, 1.12)),
    CarConstant("accel_fade_mps", 0.0, "m/s", "the acceleration falls as 1 - (v / fade)², < 0 above it (ROS 1)",
                NON_NEGATIVE, plausible=(0.0, 20.0), off=0.0, packed="value", randomised=0.0,
                fit=Search(0.0, 1.0, inverse=True)),
    CarConstant("steer_kick", 0.0, "", "share of a steering command's change the hinge takes at once (ROS 1's PID "
                "derivative)", Range(0.0, 1.0), plausible=(0.0, 1.0), packed="value", randomised=0.0,
                fit=Search(0.0, 0.9)),
    # the draws stop at 1 m/s² of saturation, and so does the fit: 0 would switch it off, the car turning hardest
    CarConstant("tyre_sat_mps2", 0.0, "m/s²", "the tyres saturate toward this lateral acceleration: κ / √(1 + "
                "(v²κ / it)²)", NON_NEGATIVE, plausible=(0.0, 50.0), off=0.0, packed="value", randomised=1.0,
                fit=Search(0.0, 1.0, inverse=True, only_if_on=True)),
    CarConstant("front_drive", 0.0, "", "share of the speed change the steered front wheels push along their angle",
                NON_NEGATIVE, plausible=(0.0, 5.0), off=0.0, packed="value", randomised=0.0,
                fit=Search(0.0, 2.0, only_if_on=True)),
    CarConstant("steer_offset_deg", 0.0, "degrees", "the wheels point this much left (+) of the command (the 2022 "
                "logs)", Range(), plausible=(-5.0, 5.0), off=0.0, packed="radians",
                fit=Search(-3.0, 3.0, only_if_on=True)),
    # fixed per car
    CarConstant("wheel_cap_mps", WHEEL_CAP_MPS, "m/s", "commands above it are clipped by the wheel joints' velocity "
                "limit", POSITIVE, plausible=(0.1, 20.0), packed="value"),
    CarConstant("regulated", True, "", "False: effort control without a speed loop (droa, version 3-4): full "
                "traction always", packed="value"),
    CarConstant("grip_mps2", 4.9, "m/s²", "lateral acceleration limit (mu 0.5 x g)", POSITIVE, plausible=(0.1, 50.0),
                packed="value"),
    # how racerlab drives it
    CarConstant("step_jitter", False, "", "steps last a length drawn from the simulator's measured distribution "
                "(training: on)"),
    CarConstant("randomise", 0.0, "spreads", "each episode draws the constants around these, this many times the "
                "fit's spread", NON_NEGATIVE, plausible=(0.0, 5.0)),
    CarConstant("substeps", 4, "", "integration sub-steps per step", Range(1.0), plausible=(1, MAX_SUBSTEPS),
                packed="value"),
)


@functools.cache
def constants_by_name(table: tuple[CarConstant, ...] = CAR_CONSTANTS) -> dict[str, CarConstant]:
    """`table`'s rows by name."""
    return {c.name: c for c in table}


def car_fields(table: tuple[CarConstant, ...]):
    """A class decorator: the class as a frozen dataclass whose fields are `table`'s rows, in order, with their
    defaults and the types of their defaults; `TABLE` (a class attribute) is the table, which its validation, packing,
    randomisation and fit read."""

    def build(cls):
        cls.__annotations__ = {c.name: type(c.default) for c in table}
        for c in table:
            setattr(cls, c.name, c.default)
        cls.TABLE = table
        return dataclass(frozen=True)(cls)

    return build


@car_fields(CAR_CONSTANTS)
class CarParams:
    """The car's geometry and dynamics: one field per row of `CAR_CONSTANTS` (name, default, unit, meaning); the
    defaults are the `droa` simulator's car for a version-5 model.

    `racerlab.sim.car` has the model (its docstring says what each constant does) and `car_params` picks
    the fitted constants of a simulator and model version (`CAR_TABLE`, fitted by `racerlab.calibrate`).
    """

    def __post_init__(self):
        where = type(self).__name__
        for c in self.TABLE:
            value = getattr(self, c.name)
            if c.valid is not None and not c.valid.holds(value):
                raise ValueError(f"{where}.{c.name} must be {c.valid.words()}")
            if c.choices and value not in c.choices:
                raise ValueError(f"{where}.{c.name} must be one of {c.choices}, got {value!r}")
        if not self.min_speed_mps <= self.max_speed_mps:
            raise ValueError(f"{where} needs 0 <= min_speed_mps <= max_speed_mps")
        if not abs(self.steer_offset_deg) < self.max_steer_deg:
            raise ValueError(f"{where}.steer_offset_deg must be within ±max_steer_deg")

    def has(self, name: str) -> bool:
        """The term of constant `name` is on: its value is not the row's `off` (a constant without one always is)."""
        off = constants_by_name(self.TABLE)[name].off
        return off is None or getattr(self, name) != off

    def wheel_offsets(self) -> np.ndarray:
        """(4, 2) wheel-centre offsets in the car frame: left rear, left front, right rear, right front."""
        hx, hy = self.wheelbase_m / 2, self.track_m / 2
        return np.array([[-hx, hy], [hx, hy], [-hx, -hy], [hx, -hy]], dtype=np.float64)

    @property
    def name(self) -> str:
        """Which car this is, for logs and prints: e.g. "droa, velocity control (version >= 5)"."""
        which = "version >= 5" if self.control == "velocity" else "version 3-4"
        return f"{self.simulator}, {self.control} control ({which})"

    def top_speed(self) -> float:
        """The fastest ground speed the car settles at, m/s (the fade speed, where the acceleration runs out, caps
        it)."""
        top = self.ground_factor * (self.wheel_cap_mps if not self.regulated
                                    else min(self.max_speed_mps, self.wheel_cap_mps))
        return min(top, self.accel_fade_mps) if self.accel_fade_mps > 0 else top

    def accel_limit(self, v):
        """The most the ground speed can gain per second at `v` (m/s², scalar or array; `sim.car.accel_limit`)."""
        v = np.asarray(v, dtype=np.float64)
        a = self.accel_mps2 * (1.0 - (v / self.accel_fade_mps) ** 2) if self.accel_fade_mps > 0 else \
            self.accel_mps2 + 0.0 * v
        return np.maximum(a, -self.brake_mps2)

    def saturated(self, kappa, v):
        """The curvature the car drives at ground speed `v` where the wheels alone (gain, slide) would bend the path
        by `kappa` (1/m): the tyres saturate toward `tyre_sat_mps2` of lateral acceleration (`sim.car`)."""
        kappa = np.asarray(kappa, dtype=np.float64)
        if self.tyre_sat_mps2 <= 0:
            return kappa + 0.0
        a = np.asarray(v, dtype=np.float64) ** 2 * kappa / self.tyre_sat_mps2
        return kappa / np.sqrt(1.0 + a * a)

    def unsaturated(self, kappa, v):
        """The inverse of `saturated`: the curvature the wheels must ask for so that the car drives `kappa` at `v`
        (a bend whose lateral acceleration reaches `tyre_sat_mps2` cannot be held: asked for as if at 0.999 of it)."""
        kappa = np.asarray(kappa, dtype=np.float64)
        if self.tyre_sat_mps2 <= 0:
            return kappa + 0.0
        a = np.clip(np.asarray(v, dtype=np.float64) ** 2 * kappa / self.tyre_sat_mps2, -0.999, 0.999)
        return kappa / np.sqrt(1.0 - a * a)

    def yaw_gain_at(self, v):
        """The effective yaw gain at ground speed `v` (scalar or array)."""
        if self.slide_mps <= 0:
            return self.yaw_gain + 0.0 * np.asarray(v, dtype=np.float64)
        return self.yaw_gain / (1.0 + (np.asarray(v, dtype=np.float64) / self.slide_mps) ** 2)


# The fitted cars: (simulator, control) -> the constants that differ from CarParams' defaults. Fitted by
# `racerlab calibrate` on the shared real logs (docs/car.md has the fits, their spread and held-out errors).
CAR_TABLE: dict[tuple[str, str], dict] = {
    # DRoA 2026 (simapp 6.0, commands up to 2.5 m/s), 867 fitted stretches: the defaults above
    ("droa", "velocity"): {},
    # no log: the code's effort controllers forward the command as a torque clipped to 10 N·m (facts §3), so the
    # droa car without a speed loop, the rest unverified
    ("droa", "effort"): {"control": "effort", "regulated": False},
    # console August 2025 (simapp 5.0, ROS 1, commands 0.5-1.0 m/s) and October 2025 (three runs at up to 3.5-4 m/s),
    # 5 723 fitted stretches: about 3 m/s² from a standstill, fading as 1 - (v / 4.47)² (2.05 m/s² at 2.5 m/s); the
    # tyres saturate toward 2.85 m/s² of lateral acceleration (which replaces the slide of the fits before: fitted
    # together, the slide goes to none); the driven front wheels turn the car more while it speeds up and less while it
    # brakes (front_drive, issue 34's third round); gazebo_ros_control saturates velocity commands at the URDF's
    # 100 rad/s: the same 3.5 m/s cap as ROS 2
    ("console", "velocity"): {"simulator": "console", "delay_steps": 0.467, "steer_tau_s": 0.0057, "yaw_gain": 0.613,
                              "slide_mps": 0.0, "yaw_tau_s": 0.092, "speed_tau_s": 0.123, "accel_mps2": 2.98,
                              "brake_mps2": 6.01, "ground_factor": 1.043, "accel_fade_mps": 4.47,
                              "tyre_sat_mps2": 2.85, "front_drive": 0.716},
    # DRfC July 2022 (model version 4) and the console's June 2022 export, 2 715 fitted stretches (steps of 1/15 s:
    # these logs' tstamps carry no motion, so the start's speed and yaw rate are measured over two steps); an effort
    # command is saturated in torque, not speed (a P loop on the wheel speed): no cap below the 4 m/s clip; the fit
    # finds no slide (1 / slide below the search's 1e-3) and no hinge kick, the tyres saturating toward 6.35 m/s², and
    # the wheels pointing 1.33° left of the command (both logs were driven on the counter-clockwise reinvent_base)
    ("console", "effort"): {"simulator": "console", "control": "effort", "delay_steps": 0.076, "steer_tau_s": 0.108,
                            "steer_kick": 0.0, "yaw_gain": 0.664, "slide_mps": 0.0, "yaw_tau_s": 0.350,
                            "speed_tau_s": 0.217, "accel_mps2": 30.0, "brake_mps2": 30.0, "ground_factor": 0.979,
                            "accel_fade_mps": 4.23, "wheel_cap_mps": 4.0, "tyre_sat_mps2": 6.35,
                            "steer_offset_deg": 1.33},
}
# The spread (standard deviation) of each fitted car's constants, from the fits docs/car.md lists: randomised dynamics
# (`CarParams.randomise`) draws each episode's car within it.
CAR_SPREAD: dict[tuple[str, str], dict[str, float]] = {
    # over fits on 2 resampled sets of the DRoA episodes (the fade held off: the logs stop at 2.5 m/s)
    ("droa", "velocity"): {"delay_steps": 0.0043, "steer_tau_s": 0.0018, "yaw_gain": 0.0007, "yaw_tau_s": 0.002,
                           "speed_tau_s": 0.011, "accel_mps2": 1.1, "brake_mps2": 0.14, "ground_factor": 0.0005},
    ("droa", "effort"): {},  # no log
    # over the three October 2025 runs fitted one by one (the runs that cover the car's whole speed range)
    ("console", "velocity"): {"delay_steps": 0.043, "steer_tau_s": 0.0037, "yaw_gain": 0.12, "yaw_tau_s": 0.009,
                              "speed_tau_s": 0.016, "accel_mps2": 0.17, "brake_mps2": 1.54, "ground_factor": 0.0078,
                              "accel_fade_mps": 0.091, "tyre_sat_mps2": 0.72, "front_drive": 0.10},
    # over fits on 2 resampled sets of the 2022 episodes (the wheels' offset, ± 0.034°, is not drawn)
    ("console", "effort"): {"delay_steps": 0.0054, "steer_tau_s": 0.0015, "yaw_gain": 0.0073, "yaw_tau_s": 0.0032,
                            "speed_tau_s": 0.0014, "ground_factor": 0.001, "tyre_sat_mps2": 0.36},
}
# The measured step lengths (s) of each simulator at the quantiles STEP_QUANTILES: simtrace tstamp differences of the
# shared logs (droa: the DRoA 2026 runs, 2 026 steps; console: DRfC 2022, console 2022 and 2025, 99 830 steps), the
# 1 % at each end left out, scaled by < 3 % so that the mean is 1/15 s (the simulator's clock counts 1/15 s a
# step). The simulator draws each car's step from them (inverse CDF, linear between quantiles) when
# `step_jitter` is on.
STEP_QUANTILES = tuple(i / 10 for i in range(11))
STEP_LENGTHS: dict[str, tuple[float, ...]] = {
    "droa": (0.0466, 0.0554, 0.0592, 0.0622, 0.0631, 0.0641, 0.0651, 0.067, 0.0699, 0.0738, 0.1272),
    "console": (0.031, 0.054, 0.06, 0.063, 0.065, 0.067, 0.069, 0.071, 0.074, 0.079, 0.099),
}
CAR_KEYS = tuple(c.name for c in CAR_CONSTANTS)


def control_of(version) -> str:
    """The actuation a model_metadata `version` gets: "velocity" from 5 on, "effort" before (facts §3)."""
    try:
        v = float(str(version).strip() or "5")
    except ValueError:
        raise ConfigError(f"model version {version!r} is not a number; write e.g. \"5\"") from None
    return "velocity" if v >= 5 else "effort"


def car_params(simulator: str = DEFAULT_SIMULATOR, version="5", **overrides) -> CarParams:
    """The fitted car of `simulator` for a model of `version`, with any constant of `overrides` replaced."""
    if simulator not in SIMULATORS:
        raise ConfigError(f"unknown simulator {simulator!r}; use one of {', '.join(SIMULATORS)}")
    unknown = sorted(set(overrides) - set(CAR_KEYS))
    if unknown:
        raise ConfigError(f"unknown car constant {unknown[0]!r}; use one of {', '.join(CAR_KEYS)}")
    return CarParams(**{**CAR_TABLE[(simulator, control_of(version))], **overrides})


# ---- episode statuses -------------------------------------------------------------------------------------
# The simtrace's episode_status values the simulator produces, indexed by its status code.
STATUS_NAMES = ("in_progress", "lap_complete", "crashed", "off_track", "immobilized", "reversed", "prepare",
                "pause", "time_up")
# Every AWS status (simapp `EpisodeStatus`) with its label in the metrics JSON; "park" (a car parked after
# its race in multi-car events) is one racerlab does not produce yet but reads in AWS logs.
STATUS_LABELS = {"prepare": "Prepare", "in_progress": "In progress", "off_track": "Off track",
                 "crashed": "Crashed", "immobilized": "Immobilized", "reversed": "Reversed",
                 "lap_complete": "Lap complete", "pause": "Pause", "park": "Park", "time_up": "Time Up"}


# ---- races ------------------------------------------------------------------------------------------------
RACE_TYPES = ("time_trial", "object_avoidance", "head_to_bot", "head_to_model")
OBSTACLE_TYPES = ("box_obstacle", "deepracer_box_obstacle", "amazon_box_obstacle")


def _parse_position(item, where: str) -> tuple[float, int]:
    """(fraction, lane) from DRfC's "0.2,1" string or a [0.2, 1] pair."""
    if isinstance(item, str):
        parts = item.replace(";", ",").split(",")
    else:
        parts = list(item) if isinstance(item, list | tuple) else [item]
    try:
        if len(parts) != 2:
            raise ValueError
        frac, lane = float(parts[0]), float(parts[1])
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: object_positions entry {item!r} is not a (fraction of the lap, lane) pair; "
                          f"write e.g. [0.25, 1] or \"0.25,1\"") from None
    if not 0.0 <= frac < 1.0:
        raise ConfigError(f"{where}: object_positions fraction {frac} is outside [0, 1); give the box's place as "
                          "a fraction of the lap")
    if lane not in (1.0, -1.0):
        raise ConfigError(f"{where}: object_positions lane {parts[1]!r} must be 1 (inner lane) or -1 (outer lane)")
    return frac, int(lane)


# ---- evaluation race rules: DRfC's DR_EVAL_* defaults and the simapp's (facts §8); `evaluate.RaceRules` --
EVAL_TRIALS = 3  # DR_EVAL_NUMBER_OF_TRIALS
EVAL_OFF_TRACK_PENALTY_S = 5.0  # DR_EVAL_OFF_TRACK_PENALTY
EVAL_COLLISION_PENALTY_S = 5.0  # DR_EVAL_COLLISION_PENALTY
EVAL_MAX_RESETS = 100  # DR_EVAL_MAX_RESETS (NUMBER_OF_RESETS)
EVAL_MAX_RESETS_AFTER_CRASH = 3  # simapp MAX_RESETS_AFTER_CRASH
EVAL_RESET_AHEAD_DIST_M = 1.0  # simapp RESET_AHEAD_DIST (racerlab's choice: RESET_BEHIND_DIST's 1 m)

# ---- model archives ---------------------------------------------------------------------------------------
MAX_ARCHIVE_BYTES = 4 << 30  # a DeepRacer model archive unpacks to far less; more is refused before unpacking


@dataclass(frozen=True)
class RaceConfig:
    """A race's settings with DRfC's names (lower case); `where` names the source in error messages.

    `type` is "time_trial", "object_avoidance", "head_to_bot" or "head_to_model" (cars race in pairs).
    Obstacles: `number_of_obstacles`, `obstacle_type`, `randomize_obstacle_locations`, `object_positions`
    (overrides the two before it), `min_distance_between_obstacles` (% of the lap). Bot cars:
    `number_of_bot_cars`, `randomize_bot_car_locations`, `bot_car_speed` (m/s), `is_lane_change`,
    `lower_lane_change_time` / `upper_lane_change_time` (s), `lane_change_distance` (m),
    `min_distance_between_bot_cars` (m). `penalty_seconds`: how long bots wait after one ran into the car.
    """

    type: str = "time_trial"
    number_of_obstacles: int = 0
    obstacle_type: str = "box_obstacle"
    randomize_obstacle_locations: bool = False
    object_positions: tuple = ()
    min_distance_between_obstacles: float = 2.0
    number_of_bot_cars: int = 0
    randomize_bot_car_locations: bool = False
    bot_car_speed: float = 0.2
    is_lane_change: bool = False
    lower_lane_change_time: float = 3.0
    upper_lane_change_time: float = 5.0
    lane_change_distance: float = 1.0
    min_distance_between_bot_cars: float = 2.0
    penalty_seconds: float = 2.0
    where: str = field(default="race", compare=False)

    def __post_init__(self):
        w = self.where
        if self.type not in RACE_TYPES:
            raise ConfigError(f"{w}: type {self.type!r} is not one of {', '.join(RACE_TYPES)}")
        if self.obstacle_type not in OBSTACLE_TYPES:
            raise ConfigError(f"{w}: obstacle_type {self.obstacle_type!r} is not one of {', '.join(OBSTACLE_TYPES)}")
        for key in ("randomize_obstacle_locations", "randomize_bot_car_locations", "is_lane_change"):
            if not isinstance(getattr(self, key), bool):
                raise ConfigError(f"{w}: {key} must be true or false, got {getattr(self, key)!r}")
        for key in ("number_of_obstacles", "number_of_bot_cars"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ConfigError(f"{w}: {key} must be a whole number >= 0, got {v!r}")
        for key in ("min_distance_between_obstacles", "min_distance_between_bot_cars", "penalty_seconds",
                    "lower_lane_change_time", "upper_lane_change_time", "lane_change_distance", "bot_car_speed"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
                raise ConfigError(f"{w}: {key} must be a number >= 0, got {v!r}")
        if self.lower_lane_change_time > self.upper_lane_change_time:
            raise ConfigError(f"{w}: lower_lane_change_time {self.lower_lane_change_time} is above "
                              f"upper_lane_change_time {self.upper_lane_change_time}; swap them")
        positions = tuple(_parse_position(p, w) for p in self.object_positions)
        object.__setattr__(self, "object_positions", positions)
        if self.head_to_model and (self.number_of_obstacles or positions or self.number_of_bot_cars):
            raise ConfigError(f"{w}: a head_to_model race puts only the racing cars on the track (racerlab has no "
                              "boxes or bot cars beside them); set number_of_obstacles = 0, object_positions = [] "
                              "and number_of_bot_cars = 0, or race object_avoidance / head_to_bot")
        if self.number_of_obstacles * self.min_distance_between_obstacles >= 100.0:
            raise ConfigError(f"{w}: number_of_obstacles {self.number_of_obstacles} boxes at least "
                              f"min_distance_between_obstacles {self.min_distance_between_obstacles} % of the lap "
                              "apart do not fit on one lap; use fewer boxes or a smaller distance")

    @property
    def num_obstacles(self) -> int:
        """Boxes on the track: the fixed positions when given, else `number_of_obstacles` (in an object
        avoidance race; a time trial has none)."""
        if self.type != "object_avoidance":
            return 0
        return len(self.object_positions) or self.number_of_obstacles

    @property
    def num_bot_cars(self) -> int:
        """Bot cars on the track (in a head-to-bot race)."""
        return self.number_of_bot_cars if self.type == "head_to_bot" else 0

    @property
    def head_to_model(self) -> bool:
        """Cars race in pairs (0 and 1, 2 and 3, ...): each pair's cars are each other's object."""
        return self.type == "head_to_model"

    @property
    def has_objects(self) -> bool:
        return self.num_obstacles + self.num_bot_cars > 0 or self.head_to_model

    def table(self) -> dict:
        """These settings as a `[race]` table (DRfC's names)."""
        return {k: [list(p) for p in getattr(self, k)] if k == "object_positions" else getattr(self, k)
                for k in self.__dataclass_fields__ if k != "where"}

    @classmethod
    def from_mapping(cls, table, where: str = "race") -> RaceConfig:
        """From a `[race]` table (keys as DRfC names them, lower case); unknown keys are one clear error."""
        known = set(cls.__dataclass_fields__) - {"where"}
        for key in table:
            if key not in known:
                raise ConfigError(f"{where}: unknown key {key!r}; the race keys are {', '.join(sorted(known))}")
        return cls(**{k: tuple(v) if k == "object_positions" else v for k, v in table.items()}, where=where)



# ---- reward params ----------------------------------------------------------------------------------------
class RewardParam(NamedTuple):
    name: str
    type: type  # the Python type of the value in the params dict
    unit: str
    meaning: str


REWARD_PARAMS = (
    RewardParam("all_wheels_on_track", bool, "", "all four wheel centres are inside the road"),
    RewardParam("x", float, "m", "model point (0.14 m ahead of the car's base) in the world frame"),
    RewardParam("y", float, "m", "model point in the world frame"),
    RewardParam("heading", float, "deg", "car yaw, counter-clockwise from +x, in (-180, 180]"),
    RewardParam("distance_from_center", float, "m", "model point to its projection on the centre line"),
    RewardParam("is_left_of_center", bool, "", "model point is left of the centre line in the driving direction"),
    RewardParam("is_reversed", bool, "", "the episode drives the track in reverse"),
    RewardParam("progress", float, "%", "share of the lap driven since the episode's start point"),
    RewardParam("steps", float, "", "steps of the episode so far, the prepare step included (2.0 at the first "
                "call)"),
    RewardParam("speed", float, "m/s", "commanded speed of the action (not measured, not clipped)"),
    RewardParam("steering_angle", float, "deg", "commanded steering of the action, + left (not clipped)"),
    RewardParam("track_width", float, "m", "distance between the border points nearest the centre projection"),
    RewardParam("track_length", float, "m", "length of the centre line"),
    RewardParam("waypoints", list, "m", "centre-line points (x, y) in the driving direction, first == last"),
    RewardParam("closest_waypoints", list, "index", "[previous, next] waypoint by arc length"),
    RewardParam("projection_distance", float, "m", "arc length of the model point's projection from waypoint 0"),
    RewardParam("is_offtrack", bool, "", "no wheel centre is on the road (the off-track rule fired this step)"),
    RewardParam("is_crashed", bool, "", "the car hit an object this step"),
    RewardParam("sim_time", float, "s", "simulation clock"),
    RewardParam("closest_objects", list, "index", "[previous, next] object along the centre line"),
    RewardParam("objects_location", list, "m", "(x, y) of every object"),
    RewardParam("objects_left_of_center", list, "", "per object: left of the centre line"),
    RewardParam("objects_distance", list, "m", "per object: arc length of its projection from waypoint 0"),
    RewardParam("objects_distance_from_center", list, "m", "per object: distance to the centre line"),
    RewardParam("objects_heading", list, "rad", "per object: yaw of a bot car, 0 for an obstacle"),
    RewardParam("objects_speed", list, "m/s", "per object: speed of a bot car, 0 for an obstacle"),
    RewardParam("object_in_camera", bool, "", "the next object is inside the camera's view"),
)
REWARD_PARAM_NAMES = tuple(p.name for p in REWARD_PARAMS)
# The object params' values on a track without objects (AWS's defaults); lists are given as tuples and
# become a fresh list in every dict.
NO_OBJECTS = {"closest_objects": (0, 0), "objects_location": (), "objects_left_of_center": (),
              "objects_distance": (), "objects_distance_from_center": (), "objects_heading": (),
              "objects_speed": (), "object_in_camera": False}


class ParamsMaker:
    """Turns columns of values into AWS params dicts, keys in `REWARD_PARAMS` order.

    `per_row` names the keys that change from row to row; the others are the same for every row of a
    call. `maker(columns, constants)` yields one fresh dict per row; list-typed params are copied into
    a new list for every dict (AWS hands each call a deep copy), so a value may be given as a tuple.
    A list param named in `parts` (name -> length) is given as that many columns, one per element: the
    list is then made in the loop (`[prev, next]`) instead of from a column of Python sequences, which
    would cost a container object per row before the first dict is made.

        >>> make = ParamsMaker(("x", "y", "closest_waypoints", ...), parts={"closest_waypoints": 2})
        >>> for params in make({"x": xs, "y": ys, "closest_waypoints": (prev, next), ...},
        ...                    {"track_length": 23.1, ...}): ...
    """

    def __init__(self, per_row: Sequence[str], parts: Mapping[str, int] | None = None):
        parts = dict(parts or {})
        unknown = [k for k in (*per_row, *parts) if k not in REWARD_PARAM_NAMES]
        if unknown or any(k not in per_row or _TYPES[k] is not list for k in parts):
            raise ValueError(f"ParamsMaker: {unknown or list(parts)} are not (per-row list) AWS reward params")
        self.per_row = tuple(k for k in REWARD_PARAM_NAMES if k in per_row)
        self.constant = tuple(k for k in REWARD_PARAM_NAMES if k not in per_row)
        self.parts = parts
        self._rows = _row_function(self.per_row, tuple(sorted(parts.items())))
        self._row_keys = frozenset(self.per_row)
        self._const_keys = frozenset(self.constant)
        self._order = tuple((k, k in parts) for k in self.per_row)

    def __call__(self, columns: Mapping[str, Sequence], constants: Mapping[str, object]) -> Iterator[dict]:
        if columns.keys() != self._row_keys or constants.keys() != self._const_keys:
            missing = set(REWARD_PARAM_NAMES) - columns.keys() - constants.keys()
            extra = (columns.keys() | constants.keys()) - set(REWARD_PARAM_NAMES)
            raise ValueError(f"ParamsMaker: columns must be {self.per_row} and constants {self.constant} "
                             f"(missing {sorted(missing)}, unknown {sorted(extra)})")
        flat = []
        for k, split in self._order:
            if split:
                flat += columns[k]
            else:
                flat.append(columns[k])
        for k in self.constant:
            flat.append(constants[k])
        return self._rows(*flat)


_TYPES = {p.name: p.type for p in REWARD_PARAMS}


@functools.cache
def _row_function(per_row: tuple[str, ...], parts: tuple[tuple[str, int], ...]) -> Callable[..., Iterator[dict]]:
    """A generator function `rows(*columns, *constants)` whose loop body is one dict display.

    Written out from the table once per set of per-row keys because a dict display is the fastest way
    CPython builds a dict (this runs once per car and step, next to the user's reward function);
    `[*v]` is the cheapest fresh list of v.
    """
    split = dict(parts)
    row_vars: list[str] = []
    const_vars: list[str] = []
    items = []
    for p in REWARD_PARAMS:
        if p.name in split:
            names = [f"r{len(row_vars) + j}" for j in range(split[p.name])]
            row_vars += names
            value = f"[{', '.join(names)}]"
        else:
            names = row_vars if p.name in per_row else const_vars
            names.append(f"{'r' if names is row_vars else 'k'}{len(names)}")
            value = f"[*{names[-1]}]" if p.type is list else names[-1]
        items.append(f"{p.name!r}: {value}")
    columns = [f"c{i}" for i in range(len(row_vars))]
    source = (f"def rows({', '.join([*columns, *const_vars])}):\n"
              f"    for ({', '.join(row_vars)},) in zip({', '.join(columns)}, strict=True):\n"
              f"        yield {{{', '.join(items)}}}\n")
    namespace: dict = {}
    exec(compile(source, f"<racerlab.spec params rows {len(per_row)}>", "exec"), namespace)  # noqa: S102
    return namespace["rows"]


# ---- plausible cars ---------------------------------------------------------------------------------------
# What a [car] table may set each constant to (the `plausible` column of CAR_CONSTANTS): CarParams takes any valid
# value (tests build extreme cars), a user's table is checked against these, wide around every fitted car
# (docs/car.md), so that a wheelbase in mm, a steering limit in radians or an inf is one line, not a silent nonsense
# car or a hang.
CAR_PLAUSIBLE: dict[str, tuple[float, float, str]] = {  # name -> (low, high, unit)
    c.name: (*c.plausible, c.unit) for c in CAR_CONSTANTS if c.plausible is not None}


def implausible(name: str, value, table: tuple[CarConstant, ...] = CAR_CONSTANTS) -> str | None:
    """Why `value` is no plausible `name` for a DeepRacer car (the `plausible` column of `table`), or None when it
    is."""
    row = constants_by_name(table).get(name)
    if row is None or row.plausible is None or isinstance(value, bool) or not isinstance(value, int | float):
        return None
    low, high = row.plausible
    if math.isfinite(value) and low <= value <= high:
        return None
    return f"{value!r} is not a plausible value for a DeepRacer car; give {low:g} to {high:g} {row.unit}".rstrip()
