"""The camera's default look, the AWS simulator's: grey levels of the walls, the sky above them, the field and the
asphalt; paint widths in pixels worked out from the camera geometry; the grain fixed to the ground; stereo."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from racerlab.sim import Simulator
from racerlab.sim.sensors import Camera
from racerlab.sim.sensors.geometry import CameraModel, camera_position
from racerlab.sim.sensors.look import LOOKS, TrackLook
from racerlab.track import from_array

HALF_WIDTH = 0.5
START_X = -5.0  # the straight's first waypoint: arc length 0
LOOK = TrackLook()
CAM_X, CAM_Z = camera_position()[0], LOOK.camera_z  # the height the simulator's frames show
WALL_Y = HALF_WIDTH + LOOK.wall_margin_m  # the walls beside the straight
INCH = 0.0254


@pytest.fixture(scope="module")
def straight():
    """A straight open road along +x from x = -5 to 40, 1 m wide, centred on y = 0 (left border y = +0.5)."""
    x = np.linspace(START_X, 40.0, 91)
    z = np.zeros_like(x)
    return from_array(np.column_stack([x, z, x, z + HALF_WIDTH, x, z - HALF_WIDTH]), name="straight")


def render(track, x, y, yaw, stereo=False, look=None):
    sim = Simulator(track, 1, seed=0)
    sim.set_pose(0, x, y, yaw)
    return Camera(sim, stereo=stereo, look=look).render()[0].astype(float)


def row_of(ahead_m, height_m=0.0):
    """Continuous image row of a point `ahead_m` ahead of the car's base, on its axis, `height_m` above the ground."""
    return float(CameraModel().project(np.array([ahead_m, 0.0, height_m]), (CAM_X, 0.0, CAM_Z))[1])


def test_the_materials_have_the_simulators_greys():
    g = LOOK.grey()
    names = ("road", "line", "center", "ground", "sky", "wall")
    want = (85.0, 254.0, 190.0, 166.0, 179.0, 84.0)  # measured on the real frames; Gazebo's 0.7 grey background
    assert dict(zip(names, np.round(g[[0, 1, 2, 3, 4, 7]], 1), strict=True)) == pytest.approx(
        dict(zip(names, want, strict=True)), abs=0.1)


def test_a_wall_across_the_view_starts_on_the_row_the_geometry_predicts(straight):
    """Facing the wall beside the straight: the wall down to the row where its base lies, then the field, then the
    white border line as many rows thick as its 3 inches span at that distance."""
    img = render(straight, 0.0, 0.0, math.pi / 2)[:, :, 0]
    base = row_of(WALL_Y)  # 1.41 m ahead of the car's base: about row 43
    assert 41 < base < 45 and row_of(WALL_Y, LOOK.wall_height_m) < 0  # the wall fills the top of the frame
    assert np.all(img[:math.floor(base)] == 84)
    field = img[math.ceil(base) + 1:int(row_of(HALF_WIDTH + 0.05))]
    assert field.mean() == pytest.approx(166, abs=4) and field.std() > 5  # grainy green field
    # the border line from 0.5 - 3 in to 0.5 m ahead: the rows whose centres fall inside it are white
    near, far = row_of(HALF_WIDTH - 3 * INCH), row_of(HALF_WIDTH)
    white = np.flatnonzero(img[:, 40:120].mean(axis=1) > 240)
    assert white.size == pytest.approx(near - far, abs=1.5)
    assert white.min() >= math.floor(far) and white.max() <= math.ceil(near)


def dash_row_and_pose(row):
    """(distance ahead of the base of image row `row`'s ground line, its lateral step per column)."""
    dist, dy = CameraModel().ground_line(row + 0.5, CAM_Z)
    return CAM_X + float(dist), abs(float(dy))


@pytest.mark.parametrize("row", [70, 100])
def test_the_centre_line_is_one_inch_wide_in_two_inch_dashes(straight, row):
    ahead, step = dash_row_and_pose(row)
    period = 4 * INCH  # open track: 2 in dashes from arc length 0, then 2 in gaps
    for phase, dash in ((1 * INCH, True), (3 * INCH, False)):  # the middle of a dash, then of a gap
        x = START_X + 40 * period + phase - ahead
        line = render(straight, x, 0.0, 0.0)[row, :, 0]
        lit = np.flatnonzero(line > (85 + 190) / 2)
        if dash:
            assert lit.size == pytest.approx(INCH / step, abs=1.5)  # 1 in across at this distance, in columns
            assert abs(lit.mean() + 0.5 - 80) < 1.5  # centred straight ahead
            assert np.median(line[lit]) == pytest.approx(190, abs=8)  # its plateau (the edges blend in)
        else:
            assert lit.size == 0


def test_sky_field_and_asphalt_greys_at_a_known_pose(straight):
    ahead = render(straight, 0.0, 0.0, 0.0)[:, :, 0]
    # looking down the straight: the far wall 41 m away is low, Gazebo's grey background above it in the middle,
    # the walls beside the straight (1.41 m to either side) at the edges
    assert row_of(40.0 + LOOK.wall_margin_m, LOOK.wall_height_m) > 20
    assert np.all(ahead[:10, 70:90] == 178) and np.all(ahead[:10, :20] == 84) and np.all(ahead[:10, -20:] == 84)
    asphalt = ahead[90:, 20:60]  # left of the centre line, inside the border lines
    assert asphalt.mean() == pytest.approx(85, abs=3)
    assert 2.0 < asphalt.std() < 9.0  # the asphalt's grain (the real frames: sigma about 5)
    assert np.median(np.abs(np.diff(asphalt, axis=1))) >= 1


def test_the_grain_is_fixed_to_the_ground(straight):
    """A car moved sideways by four columns' worth of ground on row 80 sees that row's grain four columns over."""
    row = 80
    _, step = dash_row_and_pose(row)
    a = render(straight, 0.0, 0.0, 0.0)[row, :, 0]
    b = render(straight, 0.0, 4 * step, 0.0)[row, :, 0]  # 4 columns to the left: the scene moves right
    assert np.median(np.abs(np.diff(a[10:70]))) >= 1  # there is grain to compare
    same = np.abs(b[14:150] - a[10:146])
    assert np.median(same) == 0 and np.mean(same <= 1) > 0.9
    assert np.median(np.abs(b[10:146] - a[10:146])) >= 1  # unshifted, the grain differs


def test_stereo_eyes_get_the_same_look_rounded_as_pil_converts(straight):
    mono = render(straight, 0.0, 0.0, 0.0)[:, :, 0]
    pair = render(straight, 0.0, 0.0, 0.0, stereo=True)
    # the sky's RGB (179, 179, 179) has Y = 178.98: AWS's camera filter truncates it, PIL's convert("L") of the
    # stereo pair rounds it
    assert np.all(mono[:10, 70:90] == 178) and np.all(pair[:10, 70:90] == 179)
    for eye in range(2):  # asphalt left of where either eye sees the centre line (each sees it 16 columns over)
        asphalt = pair[90:, 5:40, eye]
        assert asphalt.mean() == pytest.approx(mono[90:, 5:40].mean(), abs=2)
        assert 2.0 < asphalt.std() < 9.0  # grainy as the mono frame (whose blotches differ a little)


REAL_FRAMES = Path(__file__).resolve().parents[2].parent / "shared" / "reference" / "gazebo_frames"
BANDS = (45, 60, 80, 100, 112)  # 8-row bands of the ground, from near the horizon to the bottom


def eye_shift(pair, r0):
    """The whole-pixel shift of the right eye's rows r0..r0+7 that lines them up best with the left eye's."""
    left, right = pair[r0:r0 + 8, :, 0].astype(float), pair[r0:r0 + 8, :, 1].astype(float)
    err = [np.abs(left[:, s:] - right[:, :160 - s]).mean() for s in range(60)]
    return int(np.argmin(err))


def test_the_stereo_eyes_see_the_ground_shifted_as_in_the_simulators_frames(straight):
    """The disparity between the eyes on the ground grows by B·cos(15°)/h pixels a row below the horizon (B = 6 cm
    apart, h the camera's height): the real road frames' pairs show it, and racerlab's show the same shift on every
    band (at the URDF's 0.130 m each would be a quarter larger: 10, 17, 26, 34, 40 px)."""
    pair = render(straight, 0.0, 0.0, 0.0, stereo=True)
    m = CameraModel()
    for r0 in BANDS:
        predicted = 0.06 * math.cos(m.pitch_rad) / CAM_Z * (r0 + 4 - m.horizon_v)
        assert eye_shift(pair, r0) == pytest.approx(predicted, abs=1.0)
    frames = [REAL_FRAMES / f"{name}.npy" for name in ("stereo_cameras_state", "stereo_cameras_lidar_state")]
    if not all(f.is_file() for f in frames):
        pytest.skip(f"the real frames are not in {REAL_FRAMES}")
    for f in frames:  # on the road, the dashed centre line ahead
        real = np.load(f)
        assert [abs(eye_shift(real, r0) - eye_shift(pair, r0)) <= 1 for r0 in BANDS] == [True] * len(BANDS)


def test_the_classic_look_is_kept(straight):
    img = render(straight, 0.0, 0.0, 0.0, look=LOOKS["classic"])[:, :, 0]
    assert img[0].mean() > 180  # its light sky
    assert img[100:, 20:60].std() == 0  # flat paint, no grain


CAMERA_META = {"action_space": {"steering_angle": {"low": -30.0, "high": 30.0}, "speed": {"low": 0.5, "high": 2.0}},
               "action_space_type": "continuous", "sensor": ["FRONT_FACING_CAMERA"],
               "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", "training_algorithm": "clipped_ppo",
               "version": "5"}


def _frame(world):
    world.sim.set_pose(0, 0.0, 0.0, 0.0)
    return world.observe()[0, :, :, 0]


def test_training_toml_look_classic_gives_training_evaluation_and_the_env_the_classic_frames(straight, tmp_path):
    """run.look = "classic" reaches the camera of the training worlds, of an evaluation's world and of the env: each
    renders what a camera built with LOOKS["classic"] renders, and not the AWS look."""
    from racerlab.evaluate.api import make_world
    from racerlab.evaluate.rules import RaceRules
    from racerlab.model import CheckpointInfo, OpenModel, TrainingState, init_model, load_training_config
    from racerlab.sim.env import DeepRacerEnv
    from racerlab.train.worlds import WorldBuilder

    want = {name: render(straight, 0.0, 0.0, 0.0, look=LOOKS[name])[:, :, 0] for name in LOOKS}
    assert np.abs(want["classic"] - want["aws"]).mean() > 20  # the two looks differ a lot: a real check

    folder = init_model(tmp_path / "m", sensor="camera")
    folder.config_path.write_text('[run]\nlook = "classic"\nnum_cars = 1\n[evaluation]\nepisodes = 1\n')
    cfg = load_training_config(folder.config_path)
    assert cfg.run.look == "classic" and 'look = "classic"' in cfg.to_toml()
    builder = WorldBuilder(cfg, CAMERA_META, None)
    got = {"training": _frame(builder.world(straight, 1, seed=0))}  # evaluation_world() is a builder.world too
    model = OpenModel(folder, folder.metadata(), CheckpointInfo.of(0, 0), TrainingState({}))  # no weights: no driving
    got["evaluation"] = _frame(make_world(model, straight, RaceRules()))
    env = DeepRacerEnv(straight, model_metadata=CAMERA_META, look="classic", render_mode="rgb_array")
    got["env"] = _frame(env.world)
    env.sim.set_pose(0, 0.0, 0.0, 0.0)
    got["env render"] = env.render()[:, :, 0]
    for where, frame in got.items():
        assert np.array_equal(frame, want["classic"]), where
    aws = WorldBuilder(load_training_config(tmp_path / "none.toml"), CAMERA_META, None).world(straight, 1, seed=0)
    assert np.array_equal(_frame(aws), want["aws"])  # no file, no key: the AWS look


def test_a_look_option_needs_a_camera_and_a_known_name(straight):
    from racerlab.errors import ConfigError
    from racerlab.model import config
    from racerlab.sim import World

    assert tuple(LOOKS) == config.LOOKS  # training.toml's choices are the looks the camera has
    features = World(straight, 1, None, None, "features", look="classic")  # no camera: the look is moot
    assert features.observation.space.shape == World(straight, 1).observation.space.shape
    with pytest.raises(ConfigError, match="unknown option 'gazebo'"):
        World(straight, 1, CAMERA_META, None, "camera", look="gazebo")
    with pytest.raises(ConfigError, match="pick a camera's look; give at most one"):
        World(straight, 1, CAMERA_META, None, "camera:aws,classic")
    with pytest.raises(ConfigError, match="to an observation with a camera"):
        World(straight, 1, CAMERA_META, None, "lidar:classic")
