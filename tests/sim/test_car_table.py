"""The car as one table (issue 41): `spec.CAR_CONSTANTS` holds every car constant, and CarParams' fields and
validation, the plausible ranges, the packed order, the randomised draws and the fit's search are read from it; a
row added to a table (here, in a test only) is packed, validated, drawn and fitted with nothing else to change."""

from __future__ import annotations

import dataclasses
import math
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import racerlab
from racerlab.calibrate import fit as fit_mod
from racerlab.calibrate import fit_car, split, stretches
from racerlab.calibrate.run import car_toml
from racerlab.sim import car as car_mod
from racerlab.sim.car import columns, pack, randomised, rollout
from racerlab.spec import (
    CAR_CONSTANTS,
    CAR_KEYS,
    CAR_PLAUSIBLE,
    CAR_SPREAD,
    CAR_TABLE,
    NON_NEGATIVE,
    CarConstant,
    CarParams,
    Search,
    car_fields,
    car_params,
    implausible,
)
from tests.calibrate.test_fit import synthetic_log

# a term off by default, searched as its inverse and only for a car that has it, drawn no lower than 0.5 m/s
DUMMY = CarConstant("dummy_mps", 0.0, "m/s", "a test's term", NON_NEGATIVE, plausible=(0.0, 8.0), off=0.0,
                    packed="value", randomised=0.5, fit=Search(0.0, 2.0, inverse=True, only_if_on=True))
TABLE = (*CAR_CONSTANTS, DUMMY)
DummyCar = car_fields(TABLE)(type("DummyCar", (CarParams,), {"__module__": __name__}))


def test_carparams_fields_are_the_tables_rows():
    fields = dataclasses.fields(CarParams)
    assert [f.name for f in fields] == [c.name for c in CAR_CONSTANTS] == list(CAR_KEYS)
    assert len(fields) == 27
    for f, c in zip(fields, CAR_CONSTANTS, strict=True):
        assert f.default == c.default and f.type is type(c.default), c.name
    assert CarParams().yaw_gain == 0.638 and CarParams().substeps == 4 and CarParams().regulated is True
    # every fitted car and every spread names rows; a spread only rows that are drawn
    for key, constants in CAR_TABLE.items():
        assert set(constants) <= set(CAR_KEYS), key
        assert set(CAR_SPREAD[key]) <= set(car_mod.RANDOMISED), key


def test_the_rows_are_consistent():
    """What the derivations rely on: a number has a valid and a plausible range its default is in; a drawn constant
    is packed and bounded; a term fitted only where it is on has an `off`."""
    for c in CAR_CONSTANTS:
        if isinstance(c.default, bool | str):
            assert c.valid is None and c.plausible is None and c.randomised is None and c.fit is None, c.name
            assert isinstance(c.default, bool) or c.default in c.choices, c.name
            continue
        assert c.valid.holds(c.default) and c.plausible[0] <= c.default <= c.plausible[1], c.name
        assert c.packed in ("", "value", "radians"), c.name
        if c.randomised is not None:
            assert c.packed and c.valid.holds(c.randomised), c.name
        if c.fit is not None and c.fit.only_if_on:
            assert c.off is not None, c.name


def test_the_packed_order_is_the_tables():
    """`pack` lays the packed rows out in table order; the kernels' P_* positions are theirs; by hand for the 2022
    console effort car: 30° is π/6 rad, its wheels' 1.33° offset 0.02321 rad, a regulated car 1.0, 4 sub-steps 4.0."""
    car = car_params("console", "4")
    packed = pack(car)
    cols = columns()
    assert list(cols) == [c.name for c in CAR_CONSTANTS if c.packed] and len(packed) == len(cols) == 22
    assert packed[car_mod.P_MAX_STEER] == pytest.approx(math.pi / 6, abs=1e-15)
    assert packed[car_mod.P_OFFSET] == pytest.approx(0.0232129, abs=1e-7)
    assert packed[car_mod.P_REGULATED] == 1.0 and packed[car_mod.P_SUBSTEPS] == 4.0
    assert packed[car_mod.P_ACCEL] == 30.0 and packed[car_mod.P_FADE] == 4.23 and packed[car_mod.P_SAT] == 6.35
    named = {n: getattr(car_mod, n) for n in dir(car_mod) if n.startswith("P_")}
    assert sorted(named.values()) == list(range(22))  # every packed constant has its position, none twice


def test_plausible_ranges_are_the_tables():
    assert CAR_PLAUSIBLE["wheelbase_m"] == (0.05, 1.0, "m") and CAR_PLAUSIBLE["substeps"] == (1, 64, "")
    assert set(CAR_PLAUSIBLE) == {c.name for c in CAR_CONSTANTS} - {"simulator", "control", "regulated",
                                                                      "step_jitter"}
    assert implausible("max_steer_deg", 0.52) == ("0.52 is not a plausible value for a DeepRacer car; give 5 to 60 "
                                                  "degrees")


def test_a_new_row_is_validated():
    assert DummyCar().dummy_mps == 0.0 and DummyCar(dummy_mps=4.0).yaw_gain == CarParams().yaw_gain
    with pytest.raises(ValueError, match=r"^DummyCar\.dummy_mps must be >= 0$"):
        DummyCar(dummy_mps=-1.0)
    with pytest.raises(ValueError, match=r"DummyCar\.dummy_mps must be >= 0"):
        DummyCar(dummy_mps=math.nan)
    assert implausible("dummy_mps", 9.0, TABLE) == "9.0 is not a plausible value for a DeepRacer car; give 0 to 8 m/s"
    assert implausible("dummy_mps", 7.5, TABLE) is None and implausible("dummy_mps", 9.0) is None  # not in spec's


def test_a_new_row_is_packed_after_the_others_and_leaves_the_dynamics_alone():
    car = DummyCar(dummy_mps=4.0)
    assert columns(TABLE)["dummy_mps"] == 22
    assert np.array_equal(pack(car), [*pack(CarParams()), 4.0])
    start = {"x": 0.0, "y": 0.0, "heading": 0.0, "speed": 1.0, "steering_angle": 0.0}
    acts = [[20.0, 2.0]] * 10
    assert np.array_equal(rollout(start, acts, car=car), rollout(start, acts, car=CarParams()))


def test_a_new_row_is_drawn_within_its_spread_and_stays_off_when_off(monkeypatch):
    """Spread 1 m/s at randomise 2 around 4 m/s: draws from 4 - 2 x 2 x 1 = 0 to 8, stopped at the row's 0.5; a car
    without the term (0) stays without."""
    monkeypatch.setitem(CAR_SPREAD, ("droa", "velocity"), {"dummy_mps": 1.0})
    drawn = randomised(DummyCar(dummy_mps=4.0, randomise=2.0), np.random.default_rng(0), 4000)
    col = drawn[:, 22]
    assert col.min() == 0.5 and col.max() <= 8.0 and col.mean() == pytest.approx(4.0, abs=0.1)
    assert np.all(drawn[:, :22] == pack(CarParams()))  # nothing else drawn
    off = randomised(DummyCar(randomise=2.0), np.random.default_rng(0), 100)[:, 22]
    assert np.all(off == 0.0)


def test_a_new_row_is_fitted_where_the_car_has_it(monkeypatch):
    """Searched as its inverse from 0 to 2 (1/4 m/s = 0.25 in the vector), only for a car with the term: the optimiser
    is handed it last; the fit returns the car's own class, and the [car] table it writes lists it."""
    on, off = DummyCar(dummy_mps=4.0), DummyCar()
    keys = fit_mod._searched(on)
    assert list(keys)[-1] == "1/dummy_mps" and keys["1/dummy_mps"] == (0.0, 2.0)
    assert "1/dummy_mps" not in fit_mod._searched(off)
    vec = fit_mod._to_vector(on, keys)
    assert vec[-1] == 0.25
    vec[-1] = 0.5
    assert fit_mod._to_car(on, vec, keys).dummy_mps == 2.0
    handed = []
    real = fit_mod.minimize

    def spy(fun, x0, **kw):
        handed.append((x0, kw["bounds"]))
        return real(fun, x0, **kw)

    monkeypatch.setattr(fit_mod, "minimize", spy)
    fit_st, _ = split(stretches(synthetic_log(car_params("droa"), episodes=3, steps=60), every=4))
    fitted = fit_car(fit_st, on, max_evals=30)
    assert handed[0][0][-1] == 0.25 and handed[0][1][-1] == (0.0, 2.0)
    assert type(fitted) is DummyCar
    fit_car(fit_st, off, max_evals=30)
    assert len(handed[1][1]) == len(handed[0][1]) - 1  # the car without the term: not searched
    text = car_toml(fit_mod.Fit(fitted, {"dummy_mps": 0.1}, {15: 0.1}, {15: 0.2}, {15: 0.05}, len(fit_st), 0))
    assert f"\ndummy_mps = {fitted.dummy_mps:.4g}  # ± 0.1\n" in text
    assert fit_mod.FITTED == tuple(c.name for c in CAR_CONSTANTS if c.fit)  # spec's own table has no dummy


def test_the_fit_searches_the_tables_rows_in_order():
    assert list(fit_mod.BOUNDS) == ["delay_steps", "steer_tau_s", "yaw_gain", "1/slide_mps", "yaw_tau_s",
                                    "speed_tau_s", "accel_mps2", "brake_mps2", "ground_factor", "1/accel_fade_mps",
                                    "steer_kick", "1/tyre_sat_mps2", "front_drive", "steer_offset_deg"]
    assert fit_mod.INVERSE == {"1/slide_mps": "slide_mps", "1/accel_fade_mps": "accel_fade_mps",
                               "1/tyre_sat_mps2": "tyre_sat_mps2"}
    droa, console = fit_mod._searched(car_params("droa")), fit_mod._searched(car_params("console", "4"))
    assert set(fit_mod.BOUNDS) - set(droa) == {"1/tyre_sat_mps2", "front_drive", "steer_offset_deg"}
    assert set(fit_mod.BOUNDS) - set(console) == {"front_drive"}


def test_the_table_is_part_of_the_compiled_kernels_cache_key(tmp_path):
    """The packed positions are compiled into numba's kernels: a changed table must give another cache folder."""
    root = tmp_path / "racerlab"
    src = Path(racerlab.__file__).parent
    shutil.copytree(src, root, ignore=shutil.ignore_patterns("__pycache__", "data"))
    before = racerlab._compiled_sources_key(str(root))
    spec = root / "spec.py"
    spec.write_text(spec.read_text().replace('CarConstant("track_m"', 'CarConstant("track_m" ', 1))
    assert racerlab._compiled_sources_key(str(root)) != before


def test_a_replaced_car_keeps_its_class():
    assert type(replace(DummyCar(dummy_mps=1.0), yaw_gain=0.7)) is DummyCar
