"""`racerlab calibrate` refuses to fit nonsense, in one line before the fit, and writes only what training accepts:
a log given twice, copies of one episode, one episode held out against itself, a version no model has, and a
fitted constant past what a DeepRacer car has (issue 45, item 8)."""

from __future__ import annotations

import math
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from racerlab.calibrate import split, stretches
from racerlab.calibrate.fit import HORIZONS, Fit
from racerlab.calibrate.run import calibrate, car_toml, load_stretches
from racerlab.cli import main
from racerlab.errors import ConfigError
from racerlab.model.config import CarSettings
from racerlab.spec import car_params
from tests.calibrate.test_fit import TRUE, synthetic_log


def _csv(frame: pd.DataFrame, path: Path) -> Path:
    """The synthetic log as a simtrace CSV, as the real simulator writes it."""
    n = len(frame)
    last = frame["steps"].to_numpy() == frame.groupby("unique_episode")["steps"].transform("max").to_numpy()
    pd.DataFrame({
        "episode": frame["unique_episode"], "steps": frame["steps"], "X": frame["x"], "Y": frame["y"],
        "yaw": frame["yaw"], "steer": frame["steering_angle"], "throttle": frame["speed"], "action": np.zeros(n, int),
        "reward": np.ones(n), "done": last, "all_wheels_on_track": True, "progress": np.linspace(0, 50, n),
        "closest_waypoint": 0, "track_len": 20.0, "tstamp": frame["tstamp"], "episode_status": frame["episode_status"],
        "pause_duration": 0.0, "obstacle_crash_counter": 0, "wall_clock": 1.7e9 + frame["tstamp"],
    }).to_csv(path, index=False, float_format="%.6f")
    return path


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    return _csv(synthetic_log(TRUE, episodes=6), tmp_path_factory.mktemp("log") / "0-iteration.csv")


def test_the_same_log_given_twice_is_one_line_before_anything_is_read(log, tmp_path, capsys):
    for args in ([str(log), str(log)], [str(log.parent), str(log)]):
        assert main(["calibrate", *args, "--out", str(tmp_path / "car.toml")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "its episodes would count twice; give each log once" in err[0], err
    assert not (tmp_path / "car.toml").exists()


def test_a_copy_of_a_log_counts_once_with_one_warning(log, tmp_path):
    copy = tmp_path / "copy.csv"
    copy.write_bytes(log.read_bytes())
    alone = load_stretches([log])
    with pytest.warns(UserWarning, match=r"left out 6 episodes that repeat another row for row \(episode 0 of "
                                             r".*copy\.csv repeats episode 0 of .*0-iteration\.csv and 5 more\)"):
        both = load_stretches([log, copy])
    assert len(both) == len(alone) and np.unique(both.episode).size == 6


def test_fifteen_copies_of_one_episode_are_one_episode_and_that_is_refused(tmp_path):
    """Issue 45, item 8: fifteen copies of one episode were fitted as fifteen episodes (an interval of 0.075-0.075
    m)."""
    one = synthetic_log(TRUE, episodes=1, steps=400)  # 376 stretches: enough to fit, were they not all one drive
    copies = pd.concat([one.assign(unique_episode=k) for k in range(15)], ignore_index=True)
    log = _csv(copies, tmp_path / "0-iteration.csv")
    with warnings.catch_warnings(record=True) as caught, pytest.raises(ConfigError) as err:
        warnings.simplefilter("always")
        calibrate([log], resamples=0)
    assert any("left out 14 episodes that repeat another row for row" in str(w.message) for w in caught)
    assert "1 episode to replay" in str(err.value) and "needs 2 or more" in str(err.value)
    assert "\n" not in str(err.value)


def test_the_held_out_stretches_are_whole_episodes_the_fit_never_saw():
    """Issue 45, item 8: one episode was split into interleaved fit and held-out stretches, which overlap by all but
    one step."""
    st = stretches(synthetic_log(TRUE, episodes=1), every=5)
    with pytest.raises(ConfigError, match="1 episode to replay; the fit is judged on whole episodes it did not see"):
        split(st)
    st = stretches(synthetic_log(TRUE, episodes=2), every=5)
    fit_st, held = split(st)
    assert set(fit_st.episode) == {0} and set(held.episode) == {1}


@pytest.mark.parametrize("version", ["nan", "-1", "0", "7", "inf", "five"])
def test_a_version_no_model_has_is_one_line(log, tmp_path, capsys, version):
    """Issue 45, item 8: `--version nan` or `-1` fitted the effort car without a word."""
    assert main(["calibrate", str(log), "--version", version, "--out", str(tmp_path / "car.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--version {version}: give the logged model's model_metadata.json version, 1 to 6" \
        in err[0], err


def _fit_with(car, st) -> Fit:
    nan = {h: math.nan for h in HORIZONS}
    return Fit(car, {}, nan, nan, nan, len(st), len(st), st)


def test_a_fitted_constant_past_what_a_car_has_is_written_as_none(log):
    """Issue 45, item 8: `accel_fade_mps = 761.4` was merged into training.toml, which train then refused (plausible:
    0-20 m/s). A fade, slide or saturation is searched as its inverse; one found to be that large is none of it."""
    from racerlab.calibrate.run import plausible

    st = load_stretches([log])
    fit_st, held = split(st)
    raw = _fit_with(car_params("droa", step_jitter=False, accel_fade_mps=761.4, slide_mps=1.5e3), held)
    with pytest.raises(ConfigError, match="is not a plausible value for a DeepRacer car"):
        CarSettings.from_mapping(tomllib.loads(car_toml(raw))["car"])
    with pytest.warns(UserWarning, match=r"the fit found no slide_mps, accel_fade_mps in the logs "
                                             r"\(slide_mps 1500, accel_fade_mps 761\.4, past what a DeepRacer car "
                                             r"has\): written as 0, none"):
        fit = plausible(raw, fit_st, held)
    assert fit.car.accel_fade_mps == 0 and fit.car.slide_mps == 0 and fit.car.yaw_gain == raw.car.yaw_gain
    assert all(math.isfinite(v) for v in fit.held_out.values())  # measured again, on the car written
    settings = CarSettings.from_mapping(tomllib.loads(car_toml(fit))["car"])
    assert dict(settings.overrides)["accel_fade_mps"] == 0
    assert plausible(fit, fit_st, held) is fit  # nothing left to change
