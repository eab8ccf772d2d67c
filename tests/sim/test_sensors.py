"""Sensors: camera projection geometry, lidar ranges against hand-computed distances, domain
randomization, determinism, shapes per sensor combination, env_checker, and a camera training."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from racerlab.errors import ConfigError
from racerlab.sim import Simulator
from racerlab.sim.env import DeepRacerEnv, DeepRacerVectorEnv
from racerlab.sim.observations import make_observation, observation_name_for
from racerlab.sim.sensors import Camera, Lidar, build_observation
from racerlab.sim.sensors.geometry import CameraModel, camera_position, lidar_position, lidar_ray_angles
from racerlab.sim.sensors.lidar import discretized_sectors, sectors
from racerlab.sim.sensors.look import LOOKS, DomainRandomization
from racerlab.track import from_array
from tests.conftest import aws_track_path

HALF_WIDTH = 0.5
# the geometry tests draw the classic look: flat paint with 5 cm lines, no grain and no walls, so that a pixel's
# grey tells exactly what it sees (the AWS look's own tests are in test_camera_look.py)
LOOK = LOOKS["classic"]
ROAD, LINE, GROUND = LOOK.grey()[[0, 1, 3]]


@pytest.fixture(scope="module")
def straight():
    """A straight open road along +x from x = -5 to 40, 1 m wide, centred on y = 0 (left border y = +0.5)."""
    x = np.linspace(-5.0, 40.0, 91)
    z = np.zeros_like(x)
    return from_array(np.column_stack([x, z, x, z + HALF_WIDTH, x, z - HALF_WIDTH]), name="straight")


def frame_at(sim, cam, x, y, yaw):
    sim.set_pose(0, x, y, yaw)
    return cam.render()[0, :, :, 0].astype(float)


def expected_pixel(x_car, y_car):
    """(col, row) a ground point in the car frame lands on, pixel centres at integer + 0.5."""
    cx, cz = camera_position()
    return CameraModel().project(np.array([x_car, y_car, 0.0]), (cx, 0.0, cz))


# ---- camera geometry --------------------------------------------------------------------------
def test_camera_pose_follows_the_urdf():
    x, z = camera_position()
    assert x == pytest.approx(0.1453, abs=1e-3)
    assert z == pytest.approx(0.1303, abs=1e-3)
    m = CameraModel()
    assert math.degrees(m.hfov_rad) == pytest.approx(64.7, abs=0.1)
    # pitched 15° down: the horizon lies f·tan(15°) above the image centre
    assert m.horizon_v == pytest.approx(60 - m.focal_px * math.tan(math.radians(15)), abs=0.01)


def test_ground_line_projects_back_onto_its_row():
    m = CameraModel()
    cx, cz = camera_position()
    for row in (40, 70, 119):
        dist, dy = m.ground_line(row + 0.5, cz)
        for col in (0, 80, 159):
            y = dy * (col + 0.5 - 80)
            u, v = expected_pixel(cx + float(dist), float(y))
            assert (u, v) == pytest.approx((col + 0.5, row + 0.5), abs=1e-9)


def test_a_known_ground_point_lands_on_the_expected_pixel(straight):
    sim = Simulator(straight, 1, seed=0)
    cam = Camera(sim, look=LOOK)
    img = frame_at(sim, cam, 0.0, 0.0, 0.0)
    # the middle of the left border line (painted 5 cm wide inside the border) on the ground row of image row 40
    row = 40
    dist, _ = CameraModel().ground_line(row + 0.5, camera_position()[1])
    u, v = expected_pixel(camera_position()[0] + float(dist), HALF_WIDTH - 0.025)
    assert v == pytest.approx(row + 0.5)
    col = int(u)
    assert img[row, col] > LINE - 15
    assert img[row, col + 8] == pytest.approx(ROAD, abs=3)  # right of it: the road
    assert img[row, col - 8] == pytest.approx(GROUND, abs=3)  # left of it: the ground beyond the border
    # the sky on top, the road (or a dash) straight ahead
    assert img[0, 80] > 180 and img[110, 80] < 200


def line_column(img, row):
    """Middle (continuous column) of the bright run in the left half of a row: the left border line."""
    bright = np.flatnonzero(img[row, :80] > 0.5 * (LINE + GROUND))
    return 0.5 * (bright[0] + bright[-1] + 1)


def line_u(row, yaw):
    """Continuous image column of the left border line's middle on image row `row`, car at the origin turned by yaw."""
    cx, cz = camera_position()
    dist, _ = CameraModel().ground_line(row + 0.5, cz)
    x_car = cx + float(dist)
    # the border line y = 0.475 in the world, at forward distance x_car in the car frame
    y_car = (HALF_WIDTH - 0.025 - math.sin(yaw) * x_car) / math.cos(yaw)
    return float(expected_pixel(x_car, y_car)[0])


def test_the_track_edge_moves_the_right_way_when_the_car_turns(straight):
    sim = Simulator(straight, 1, seed=0)
    cam = Camera(sim, look=LOOK)
    row = 42
    yaw = math.radians(5.0)
    ahead, left, right = (frame_at(sim, cam, 0.0, 0.0, a) for a in (0.0, yaw, -yaw))
    # turning left, the world and the left border swing right in the image
    assert line_u(row, yaw) > line_u(row, 0.0) + 5
    for img, a in ((ahead, 0.0), (left, yaw), (right, -yaw)):
        assert abs(line_column(img, row) - line_u(row, a)) <= 1.0
    assert line_column(left, row) > line_column(ahead, row) > line_column(right, row)


def test_a_car_offset_to_the_left_sees_the_left_line_nearer_the_middle(straight):
    sim = Simulator(straight, 1, seed=0)
    cam = Camera(sim, look=LOOK)
    row = 42
    centred = line_column(frame_at(sim, cam, 0.0, 0.0, 0.0), row)
    offset = line_column(frame_at(sim, cam, 0.0, 0.2, 0.0), row)
    assert offset > centred + 10


def test_stereo_eyes_see_the_scene_shifted(straight):
    sim = Simulator(straight, 1, seed=0)
    cam = Camera(sim, stereo=True, look=LOOK)
    sim.set_pose(0, 0.0, 0.0, 0.0)
    f = cam.render()[0].astype(float)
    left, right = f[:, :, 0], f[:, :, 1]
    row = 42
    # the left eye sits 3 cm further left, so the left border appears further right to it
    assert line_column(left, row) > line_column(right, row)
    mono = frame_at(sim, Camera(sim, look=LOOK), 0.0, 0.0, 0.0)
    assert line_column(left, row) >= line_column(mono, row) >= line_column(right, row)


def creep(sim, cam, track, s0, steps=20):
    """Frames of a car creeping 1 cm per frame straight ahead from arc length s0; 640×480 frames box-filtered
    to 160×120, as AWS resizes its Gazebo frames."""
    x0, y0 = track.point_at(s0)
    yaw = float(track.heading_at(s0))
    out = []
    for k in range(steps):
        f = frame_at(sim, cam, x0 + 0.01 * k * math.cos(yaw), y0 + 0.01 * k * math.sin(yaw), yaw)
        out.append(f.reshape(120, f.shape[0] // 120, 160, f.shape[1] // 160).mean(axis=(1, 3)))
    return np.array(out)


def test_distant_lines_match_a_supersampled_render_and_do_not_shimmer(aws_track):
    """Rows showing ground 0.7 to 15 m ahead, against a 4×4 supersampled render (what AWS's 640×480 Gazebo
    frame resized to 160×120 is): close in every frame, and changing like it from frame to frame."""
    t = aws_track("reInvent2019_track")
    sim = Simulator(t, 1, seed=0)
    cam = Camera(sim, look=LOOK)
    ref = Camera(sim, look=LOOK, model=CameraModel(width=640, height=480))
    naive = Camera(sim, look=LOOK)
    naive.replan(max_subrows=1, level_bias=-20.0)  # one bilinear read of the finest raster per pixel
    rows = slice(26, 50)
    err, flicker, naive_flicker = [], [], []
    for s0 in np.linspace(0.0, t.length, 7)[:-1]:
        r = creep(sim, ref, t, s0)[:, rows]
        f = creep(sim, cam, t, s0)[:, rows]
        n = creep(sim, naive, t, s0)[:, rows]
        err.append(np.abs(f - r).mean())
        flicker.append(np.abs(np.diff(f, axis=0) - np.diff(r, axis=0)).mean())
        naive_flicker.append(np.abs(np.diff(n, axis=0) - np.diff(r, axis=0)).mean())
    assert np.mean(err) < 1.5
    assert np.mean(flicker) < 1.0
    assert np.mean(naive_flicker) > 2 * np.mean(flicker)  # the test can tell shimmer


def test_camera_contrast_is_like_aws(aws_track):
    """The AWS simulator's greys: asphalt about 85, white lines near 255, the centre line's dashes about 190, and
    at the top the walls (84) or Gazebo's grey background above them."""
    sim = Simulator(aws_track("reInvent2019_track"), 8, seed=0)
    f = Camera(sim).render()[:, :, :, 0]
    road = f[:, 100:, 40:120]
    assert 80 < np.median(road) < 90
    assert f[:, 30:].max() > 245  # white border lines
    assert (np.abs(f[:, 60:].astype(float) - 190) < 6).sum() > 100  # the centre line's dashes
    assert np.isin(f[:, :3], [84, 178]).mean() > 0.95  # walls or the background above them, both flat

# ---- lidar --------------------------------------------------------------------------------------
def test_lidar_rays_follow_aws_order():
    a = np.degrees(lidar_ray_angles())
    assert a.shape == (64,)
    assert a[0] == pytest.approx(30.0, abs=1e-3) and a[-1] == pytest.approx(-30.0, abs=1e-3)
    assert np.degrees(lidar_ray_angles()[31:33]) == pytest.approx([177.619, -177.619], abs=1e-2)
    assert lidar_position() == pytest.approx(0.029)


def test_lidar_range_to_a_box_behind_the_car(straight):
    sim = Simulator(straight, 1, seed=0)
    sim.set_pose(0, 0.0, 0.0, 0.0)
    lidar = Lidar(sim, noise_sigma_m=0.0)
    face = 0.4  # the box's front face is 0.4 m behind the lidar
    lidar.set_objects([[lidar_position() - face - 0.1, 0.0, 0.0, 0.2, 0.4]])
    r = lidar.scan()[0].astype(float)
    back = lidar_ray_angles() + math.pi  # angle from straight behind
    back = np.mod(back + math.pi, 2 * math.pi) - math.pi
    hits = np.abs(face * np.tan(back)) <= 0.2
    expected = np.where(hits, face / np.abs(np.cos(back)), 1.0)
    assert hits.sum() == 12  # rays 2.4°, 7.1°, ..., 26.2° either side of behind; atan(0.2 / 0.4) = 26.6°
    assert r == pytest.approx(expected, abs=1e-6)
    # the same box turned by 90° with its sides swapped reads the same
    lidar.set_objects([[lidar_position() - face - 0.1, 0.0, math.pi / 2, 0.4, 0.2]])
    assert lidar.scan()[0] == pytest.approx(expected, abs=1e-6)
    # and the car turned around sees it in front, in the camera's gap: nothing
    sim.set_pose(0, 0.0, 0.0, math.pi)
    lidar.set_objects([[-lidar_position() - face - 0.1, 0.0, 0.0, 0.2, 0.4]])
    assert (lidar.scan()[0] == 1.0).all()


def test_lidar_noise_clipping_and_sectors(straight):
    sim = Simulator(straight, 2, seed=5)
    sim.set_pose(0, 0.0, 0.0, 0.0)
    sim.set_pose(1, 10.0, 0.0, 0.0)
    lidar = Lidar(sim)
    lidar.set_objects([[lidar_position() - 0.3, 0.0, 0.0, 0.2, 0.4], [9.0, 0.0, 0.0, 0.05, 0.05]],
                      visible=[[True, False], [False, False]])
    samples = np.array([lidar.scan()[0, 31] for _ in range(2000)])
    true = 0.2 / math.cos(math.radians(180 - 177.619))
    assert samples.mean() == pytest.approx(true, abs=1e-3)
    assert samples.std() == pytest.approx(0.01, rel=0.1)
    assert (lidar.ranges[1] == 1.0).all()  # car 1 sees neither box
    lidar.set_objects([[lidar_position() - 0.12, 0.0, 0.0, 0.2, 0.4]])  # the lidar is inside the box
    assert lidar.scan()[0].min() == pytest.approx(0.15)
    ranges = np.ones((1, 64), np.float32)
    ranges[0, 31] = 0.49
    ranges[0, 32] = 0.5
    assert sectors(ranges)[0].tolist() == [0, 0, 0, 1, 0, 0, 0, 0]


def test_lidar_quick_atan2_stays_within_its_stated_error():
    # the lidar picks a segment's rays with a polynomial atan2; its error bound widens the pick (each ray is then
    # tested exactly), so the bound must hold all the way round and at any distance
    from racerlab.sim.sensors.lidar import ATAN2_ERROR_RAD, _atan2

    worst = 0.0
    for r in (1e-6, 0.3, 7.0):
        for a in np.linspace(-math.pi + 1e-9, math.pi, 20011):
            y, x = r * math.sin(a), r * math.cos(a)
            worst = max(worst, abs(_atan2(y, x) - math.atan2(y, x)))
    assert 0.0 < worst <= ATAN2_ERROR_RAD


def test_lidar_walls_are_an_option(straight):
    sim = Simulator(straight, 1, seed=0)
    sim.set_pose(0, 0.0, 0.0, 0.0)
    assert (Lidar(sim).scan()[0] == 1.0).all()  # AWS tracks have no walls
    r = Lidar(sim, walls=True, noise_sigma_m=0.0).scan()[0].astype(float)
    a = lidar_ray_angles()
    wall = HALF_WIDTH / np.maximum(np.abs(np.sin(a)), 1e-9)
    assert r == pytest.approx(np.clip(wall, 0.15, 1.0), abs=1e-6)


def test_discretized_sectors_follow_aws_filter():
    # AWS ObservationSectorDiscretizeFilter: sector minimum, clipped to clipping_dist, bin
    # floor(min / (clip / values)); the bin at clip itself (nothing seen) is dropped
    ranges = np.full((1, 64), 2.0, np.float32)
    ranges[0, 3] = 0.2  # sector 0: bin 0 of [0, 0.25)
    ranges[0, 8:16] = 1.99  # sector 1: bin 7
    ranges[0, 20] = 0.25  # sector 2: exactly on a bin edge -> bin 1
    ranges[0, 63] = 0.74  # sector 7: bin 2
    got = discretized_sectors(ranges, 8, 8, 2.0).reshape(8, 8)
    want = np.zeros((8, 8))
    want[0, 0] = want[1, 7] = want[2, 1] = want[7, 2] = 1.0
    assert got.tolist() == want.tolist()
    # 4 sectors of 16 rays, bins of 0.5 m: 0.2 | 0.25 | nothing within 1.0 | 0.74
    assert discretized_sectors(ranges, 4, 2, 1.0).reshape(4, 2).tolist() == [[1, 0], [1, 0], [0, 0], [0, 1]]


def test_discretized_sector_lidar_from_model_metadata(straight):
    meta = {"action_space": [{"steering_angle": 0, "speed": 1}], "sensor": ["FRONT_FACING_CAMERA",
            "DISCRETIZED_SECTOR_LIDAR"], "lidar_config": {"num_sectors": 4, "num_values_per_sector": 5,
                                                          "clipping_dist": 1.5}}
    env = DeepRacerEnv(straight, model_metadata=meta)
    assert env.world.observation.name == "camera+discretized_sector_lidar"
    assert env.observation_space["discretized_sector_lidar"].shape == (20,)
    env.reset(seed=0)
    sim = env.sim
    sim.set_pose(0, 0.0, 0.0, 0.0)
    lid = env.world.observation.parts["discretized_sector_lidar"]
    lid.lidar.noise_sigma_m = 0.0
    # a box 1.2 m behind the lidar: beyond the plain lidar's 1.0 m, inside clipping_dist 1.5;
    # ray 31/32 are the middle rays of sector 1 (rays 16-31) and sector 2 (rays 32-47)
    lid.lidar.set_objects([[lidar_position() - 1.2 - 0.1, 0.0, 0.0, 0.2, 0.1]])
    got = lid()[0].reshape(4, 5)
    want = np.zeros((4, 5))
    near = 1.2 / math.cos(math.radians(180 - 177.619))  # 1.201 m -> bin floor(1.201 / 0.3) = 4
    want[1, int(near // 0.3)] = want[2, int(near // 0.3)] = 1.0
    assert got.tolist() == want.tolist()
    for bad, msg in (({"num_sectors": 7}, "divide"), ({"num_values_per_sector": 0}, ">= 1"),
                     ({"clipping_dist": "far"}, "number"), ({"range": 2}, "unknown key")):
        with pytest.raises(ConfigError, match=msg):
            DeepRacerEnv(straight, model_metadata={**meta, "lidar_config": bad})


# ---- observations -------------------------------------------------------------------------------
SHAPES = {
    "camera": {"camera": ((120, 160, 1), np.uint8)},
    "stereo": {"stereo": ((120, 160, 2), np.uint8)},
    "lidar": {"lidar": ((64,), np.float32)},
    "sector_lidar": {"sector_lidar": ((8,), np.float32)},
    "camera+lidar": {"camera": ((120, 160, 1), np.uint8), "lidar": ((64,), np.float32)},
    "stereo+lidar": {"stereo": ((120, 160, 2), np.uint8), "lidar": ((64,), np.float32)},
    "camera+sector_lidar": {"camera": ((120, 160, 1), np.uint8), "sector_lidar": ((8,), np.float32)},
    "stereo+sector_lidar:dr,walls": {"stereo": ((120, 160, 2), np.uint8), "sector_lidar": ((8,), np.float32)},
    "discretized_sector_lidar": {"discretized_sector_lidar": ((64,), np.float32)},  # AWS defaults 8 × 8
}


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_shapes_and_dtypes_per_sensor_combination(aws_track, name):
    env = DeepRacerVectorEnv(3, aws_track("reInvent2019_track"), observation=name)
    obs, _ = env.reset(seed=0)
    obs, *_ = env.step(env.action_space.sample())
    parts = obs if isinstance(obs, dict) else {next(iter(SHAPES[name])): obs}
    assert set(parts) == set(SHAPES[name])
    for key, (shape, dtype) in SHAPES[name].items():
        assert parts[key].shape == (3, *shape) and parts[key].dtype == dtype
    assert env.observation_space.contains(obs)


@pytest.mark.parametrize("sensor, name", [(["FRONT_FACING_CAMERA"], "camera"), (["STEREO_CAMERAS"], "stereo"),
                                          (["FRONT_FACING_CAMERA", "LIDAR"], "camera+lidar"),
                                          (["STEREO_CAMERAS", "LIDAR"], "stereo+lidar"),
                                          (["STEREO_CAMERAS", "SECTOR_LIDAR"], "stereo+sector_lidar"),
                                          (["FRONT_FACING_CAMERA", "DISCRETIZED_SECTOR_LIDAR"],
                                           "camera+discretized_sector_lidar")])
def test_observation_follows_the_aws_sensor_list(aws_track, sensor, name):
    meta = {"action_space": [{"steering_angle": 0, "speed": 1}], "sensor": sensor}
    env = DeepRacerEnv(aws_track("reInvent2019_track"), model_metadata=meta)
    from racerlab.model import as_model_metadata

    assert observation_name_for(as_model_metadata(meta)) == name
    assert env.world.observation.name == name


@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("name", ["camera", "stereo", "lidar", "sector_lidar", "discretized_sector_lidar",
                                  "camera+lidar", "stereo+lidar", "camera:dr", "lidar:walls", "features"])
def test_env_checker_passes_for_each_observation(aws_track, name):
    check_env(DeepRacerEnv(aws_track("reInvent2019_track"), observation=name))


def test_options_are_checked(aws_track):
    sim = Simulator(aws_track("reInvent2019_track"), 1, seed=0)
    with pytest.raises(ConfigError, match="takes no options"):
        make_observation("features:dr", sim, None)
    with pytest.raises(ConfigError, match="unknown option 'fog'"):
        make_observation("camera:fog", sim, None)
    with pytest.raises(ConfigError, match="has none"):
        build_observation("lidar", sim, options=("dr",))


def run(name, seed, steps=6, cars=4):
    env = DeepRacerVectorEnv(cars, aws_track_path("reInvent2019_track"), observation=name)
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for k in range(steps):
        obs, *_ = env.step(np.full(cars, k % 10))
        out.append(obs)
    return out


def same(a, b):
    if isinstance(a, dict):
        return all(np.array_equal(a[k], b[k]) for k in a)
    return np.array_equal(a, b)


@pytest.mark.parametrize("name", ["camera:dr", "camera+lidar:dr,walls"])
def test_same_seed_same_observations(name):
    a, b, c = run(name, 3), run(name, 3), run(name, 4)
    assert all(same(x, y) for x, y in zip(a, b, strict=True))
    assert not all(same(x, y) for x, y in zip(a, c, strict=True))


def test_domain_randomization_changes_the_look_per_episode(aws_track):
    sim = Simulator(aws_track("reInvent2019_track"), 8, seed=1)
    plain, dr = Camera(sim), Camera(sim, randomization=DomainRandomization())
    p, d = plain.render().astype(float), dr.render().astype(float)
    assert not np.array_equal(p, d)
    means = d.mean(axis=(1, 2, 3))
    assert means.std() > 3  # each car has its own light
    coef = dr.lighting.coef.copy()
    sim.step(np.zeros(8), np.ones(8))
    dr.render()
    assert np.array_equal(dr.lighting.coef, coef)  # the same look for the whole episode
    sim.reset([True] + [False] * 7)
    dr.render()
    assert not np.array_equal(dr.lighting.coef[0], coef[0]) and np.array_equal(dr.lighting.coef[1:], coef[1:])
    # without randomization a car's frame depends on its pose only
    assert np.array_equal(plain.render()[1:], Camera(sim).render()[1:])


def test_domain_randomization_is_centred_on_the_default_look(aws_track):
    """Over many draws, the randomized frames' greys average to the default look's, region by region (the white
    lines' extra light clipped at 255 takes a few grey levels off); each draw differs."""
    t = aws_track("reinvent_base")
    sim = Simulator(t, 256, seed=2)
    s = np.random.default_rng(0).uniform(0.0, t.length, 256)
    for i, (x, y) in enumerate(t.point_at(s)):
        sim.set_pose(i, x, y, float(t.heading_at(s[i])))
    plain = Camera(sim).render()[..., 0].astype(float)
    dr = Camera(sim, randomization=DomainRandomization()).render()[..., 0].astype(float)
    for rows in (slice(0, 20), slice(20, 80), slice(80, 120)):
        assert dr[:, rows].mean() == pytest.approx(plain[:, rows].mean(), abs=4.0)
    assert (dr.mean(axis=(1, 2)) - plain.mean(axis=(1, 2))).std() > 5  # each car its own light


def test_partial_update_renders_only_the_given_rows(aws_track):
    sim = Simulator(aws_track("reInvent2019_track"), 4, seed=0)
    obs = build_observation("camera+lidar", sim)
    first = obs()
    sim.step(np.zeros(4), np.full(4, 2.0))
    sim.step(np.zeros(4), np.full(4, 2.0))
    part = obs(np.array([2]))
    full = obs()
    assert np.array_equal(part["camera"][2], full["camera"][2])
    assert np.array_equal(part["camera"][0], first["camera"][0])
    assert not np.array_equal(full["camera"][0], first["camera"][0])


# ---- training -----------------------------------------------------------------------------------
@pytest.mark.slow  # 1.5 to 2 minutes on 2 cores
def test_a_camera_model_trains(tmp_path):
    """Two iterations of a camera model: rollouts of rendered frames, a CNN update, the next rollout, checkpoints."""
    from racerlab.model import init_model
    from racerlab.train import train

    folder = init_model(tmp_path / "cam", track=str(aws_track_path("reInvent2019_track")), sensor="camera",
                        num_cars=4)
    hp = json.loads(folder.hyperparameters_path.read_text())
    hp.update(num_episodes_between_training=8, num_epochs=3)  # AWS's 20 x 10 takes minutes on a busy CPU
    folder.hyperparameters_path.write_text(json.dumps(hp))
    # an untrained greedy camera policy may circle on the track: cap episodes so evaluation stays short
    text = folder.config_path.read_text()
    folder.config_path.write_text(re.sub(r"(?m)^max_episode_steps = .*$", "max_episode_steps = 200", text))
    result = train(tmp_path / "cam", iterations=2, progress=False)
    assert result.iterations == 2
    assert result.env_steps > 0 and result.best_checkpoint
    assert any((tmp_path / "cam" / "checkpoints").iterdir())


# ---- racerlab sim view -----------------------------------------------------------------------------
def test_sim_view_writes_a_png(tmp_path, capsys):
    from racerlab.cli import main

    out = tmp_path / "view.png"
    assert main(["sim", "view", str(aws_track_path("reInvent2019_track")), "--out", str(out), "--cars", "3",
                 "--walls"]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "wrote" in capsys.readouterr().out
    assert main(["sim", "view", "no_such_track_anywhere", "--out", str(out)]) == 2
