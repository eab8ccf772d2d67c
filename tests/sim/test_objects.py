"""Object avoidance on real AWS tracks: placement, the crash rule and the `objects_*` params against values
worked out here from the waypoint arrays (brute-force geometry, not racerlab's projection)."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

from racerlab.errors import ConfigError
from racerlab.sim import Simulator
from racerlab.sim.objects import RaceConfig
from racerlab.sim.params import ParamsBuilder
from racerlab.spec import NO_OBJECTS, CarParams

TRACK = "reInvent2019_track"


def arc_lengths(line):
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(line, axis=0).T))])


def point_at(line, s):
    cum = arc_lengths(line)
    return np.array([np.interp(s, cum, line[:, 0]), np.interp(s, cum, line[:, 1])])


def nearest_on(line, p):
    """(nearest point, arc length there, segment heading) of polyline `line` to p, by brute force."""
    a, b = line[:-1], line[1:]
    ab = b - a
    t = np.clip(((p - a) * ab).sum(1) / (ab * ab).sum(1), 0.0, 1.0)
    q = a + t[:, None] * ab
    k = int(np.argmin(np.hypot(*(q - p).T)))
    return q[k], arc_lengths(line)[k] + t[k] * np.hypot(*ab[k]), math.atan2(ab[k, 1], ab[k, 0])


def box_pose(track, frac, lane):
    """Where AWS puts a box: the centre point at frac * L, projected onto the lane line (centre/border midline)."""
    border = track.inner if lane == 1 else track.outer
    lane_line = 0.5 * (track.center + border)
    c = point_at(track.center, frac * arc_lengths(track.center)[-1])
    q, _, yaw = nearest_on(lane_line, c)
    return q, yaw


def oa_sim(track, positions, num_cars=1, **kw):
    return Simulator(track, num_cars, race=RaceConfig(type="object_avoidance", object_positions=positions), **kw)


def test_fixed_positions_stand_on_their_lanes(aws_track):
    t = aws_track(TRACK)
    sim = oa_sim(t, [(0.25, 1), (0.6, -1)], num_cars=2)
    for j, (frac, lane) in enumerate([(0.25, 1), (0.6, -1)]):
        q, yaw = box_pose(t, frac, lane)
        for car in range(2):
            np.testing.assert_allclose(sim.objects.xy[car, j], q, atol=1e-9)
            assert sim.objects.yaw[car, j] == pytest.approx(yaw, abs=1e-9)
    sim.reset()
    np.testing.assert_allclose(sim.objects.xy[0, 0], box_pose(t, 0.25, 1)[0], atol=1e-9)  # fixed layouts repeat


def test_evenly_spaced_alternating_lanes(aws_track):
    t = aws_track(TRACK)
    sim = Simulator(t, 1, race=RaceConfig(type="object_avoidance", number_of_obstacles=4))
    length = arc_lengths(t.center)[-1]
    want = np.linspace(0.02 * length, length - 1.0, 4)  # min distance 2 % of the lap, the last 1 m before the end
    for j, s in enumerate(want):
        q, _ = box_pose(t, s / length, 1 if j % 2 == 0 else -1)
        np.testing.assert_allclose(sim.objects.xy[0, j], q, atol=1e-9)
    assert sim.objects.lane[0].tolist() == [1, -1, 1, -1]


def test_random_layouts_keep_the_minimum_gap_and_change_every_reset(aws_track):
    t = aws_track(TRACK)
    race = RaceConfig(type="object_avoidance", number_of_obstacles=5, randomize_obstacle_locations=True,
                      min_distance_between_obstacles=10.0)
    sim = Simulator(t, 3, race=race, seed=4)
    length = arc_lengths(t.center)[-1]
    layouts = []
    for _ in range(6):  # the intended minimum holds at every reset (AWS's shrinks from the second one on)
        sim.reset()
        for car in range(3):
            s = np.array([nearest_on(t.center, p)[1] for p in sim.objects.xy[car]])
            gaps = np.diff(s)
            assert s[0] >= 0.1 * length - 0.3 and s[-1] <= length - 1.0 + 0.3  # lane projection moves it a little
            assert (gaps >= 0.1 * length - 0.3).all()
            layouts.append(s)
        assert set(sim.objects.lane.ravel().tolist()) <= {1, -1}
    assert len({tuple(np.round(s, 3)) for s in layouts}) == len(layouts)


def crash_sim(t, gap):
    """A car behind the box at 0.5 of the lap in the inner lane, aligned with it; its front corners `gap` m
    before the box's footprint (negative: inside). Returns the status after one judged step."""
    sim = oa_sim(t, [(0.5, 1)])
    q, yaw = box_pose(t, 0.5, 1)
    back = 0.25 + 0.32352 / 2 + gap
    sim.set_pose(0, q[0] - back * math.cos(yaw), q[1] - back * math.sin(yaw), yaw)
    sim.step(0.0, 0.1)  # prepare
    return sim, sim.status_names(sim.step(0.0, 0.1))[0]


def test_crash_when_a_corner_is_inside_the_box_footprint(aws_track):
    t = aws_track(TRACK)
    assert crash_sim(t, -0.01)[1] == "crashed"
    assert crash_sim(t, 0.01)[1] == "in_progress"


def test_crash_footprint_is_wider_than_the_box(aws_track):
    # beside the box, 0.19 m from its lane line to the car's axis: the car's corner (0.098 m) is at 0.092 m,
    # inside the 0.2 m half-width footprint (box 0.15 m + buffer), so a crash
    t = aws_track(TRACK)
    q, yaw = box_pose(t, 0.5, 1)
    for side, want in ((0.19, "crashed"), (0.31, "in_progress")):
        sim = oa_sim(t, [(0.5, 1)])
        nx, ny = -math.sin(yaw), math.cos(yaw)
        sim.set_pose(0, q[0] - side * nx, q[1] - side * ny, yaw)
        sim.step(0.0, 0.1)
        assert sim.status_names(sim.step(0.0, 0.1))[0] == want


def test_training_episode_ends_on_a_crash(aws_track):
    t = aws_track(TRACK)
    env = gym.make("racerlab/DeepRacer-v0", track=t, race={"type": "object_avoidance", "object_positions": ["0.5,1"]},
                   reward_function=lambda p: 1.0)
    env.reset(seed=0)
    q, yaw = box_pose(t, 0.5, 1)
    env.unwrapped.sim.set_pose(0, q[0] - 0.8 * math.cos(yaw), q[1] - 0.8 * math.sin(yaw), yaw)
    straight = int(np.flatnonzero(env.unwrapped.world.commands(np.arange(env.action_space.n))[0] == 0.0)[0])
    for _ in range(60):
        _, _, terminated, truncated, info = env.step(straight)
        if terminated or truncated:
            break
    assert terminated and env.unwrapped.sim.status_names()[0] == "crashed"
    env.close()


def params_for(sim):
    sim.step(0.0, 0.1)
    sim.step(0.0, 0.1)
    return ParamsBuilder(sim).build()[0]


def test_object_params_by_hand(aws_track):
    t = aws_track(TRACK)
    positions = [(0.7, -1), (0.2, 1), (0.45, -1)]
    sim = oa_sim(t, positions)
    length = arc_lengths(t.center)[-1]
    # the car's model point on the centre line at 0.3 of the lap, heading along it
    s_car = 0.3 * length
    m = point_at(t.center, s_car)
    _, _, heading = nearest_on(t.center, m)
    sim.set_pose(0, m[0] - 0.14 * math.cos(heading), m[1] - 0.14 * math.sin(heading), heading)
    p = params_for(sim)
    boxes = [box_pose(t, f, lane)[0] for f, lane in positions]
    np.testing.assert_allclose(p["objects_location"], boxes, atol=1e-9)
    for j, b in enumerate(boxes):
        q, s, _ = nearest_on(t.center, b)
        assert p["objects_distance"][j] == pytest.approx(s, abs=1e-6)
        assert p["objects_distance_from_center"][j] == pytest.approx(np.hypot(*(b - q)), abs=1e-9)
    assert t.is_ccw  # reInvent2019 drives counter-clockwise: the inner lane is on the left
    assert p["objects_left_of_center"] == [False, True, False]
    # by arc length: box 1 (0.2) is behind the car (0.3), box 2 (0.45) is the next one ahead
    assert p["closest_objects"] == [1, 2]
    assert p["objects_heading"] == [0.0, 0.0, 0.0] and p["objects_speed"] == [0.0, 0.0, 0.0]
    assert isinstance(p["objects_location"][0], list) and p["is_crashed"] is False
    # beyond the last box the next one wraps to the first along the lap, the previous is the last
    sim2 = oa_sim(t, positions)
    m = point_at(t.center, 0.8 * length)
    _, _, heading = nearest_on(t.center, m)
    sim2.set_pose(0, m[0] - 0.14 * math.cos(heading), m[1] - 0.14 * math.sin(heading), heading)
    assert params_for(sim2)["closest_objects"] == [0, 1]


def test_object_in_camera(aws_track):
    t = aws_track(TRACK)
    q, yaw = box_pose(t, 0.5, 1)
    for back, want in ((1.5, True), (-1.0, False)):  # 1.5 m behind the box and looking at it; past it
        sim = oa_sim(t, [(0.5, 1), (0.02, -1)])
        sim.set_pose(0, q[0] - back * math.cos(yaw), q[1] - back * math.sin(yaw), yaw)
        p = params_for(sim)
        nxt = p["closest_objects"][1]
        assert (nxt == 0) == (back > 0)
        assert p["object_in_camera"] is want


def test_reversed_direction_measures_along_the_reversed_line(aws_track):
    t = aws_track(TRACK)
    sim = oa_sim(t, [(0.25, 1)])
    rt = t.reverse()
    m = point_at(rt.center, 0.1 * arc_lengths(rt.center)[-1])
    _, _, heading = nearest_on(rt.center, m)
    sim.set_pose(0, m[0] - 0.14 * math.cos(heading), m[1] - 0.14 * math.sin(heading), heading, reverse=True)
    p = params_for(sim)
    b = box_pose(rt, 0.25, 1)[0]
    np.testing.assert_allclose(p["objects_location"][0], b, atol=1e-9)
    assert p["objects_distance"][0] == pytest.approx(nearest_on(rt.center, b)[1], abs=1e-6)
    assert p["objects_left_of_center"] == [False]  # the inner lane is on the right when driving clockwise


def test_time_trial_has_no_objects(aws_track):
    sim = Simulator(aws_track(TRACK), 1)
    assert sim.objects is None
    p = params_for(sim)
    assert {k: p[k] for k in NO_OBJECTS} == {k: (list(v) if isinstance(v, tuple) else v) for k, v in NO_OBJECTS.items()}


@pytest.mark.parametrize("table, key", [
    ({"object_positions": ["1.2,1"]}, "object_positions"),
    ({"object_positions": [[0.2, 2]]}, "object_positions"),
    ({"number_of_obstacles": 30, "min_distance_between_obstacles": 5.0}, "number_of_obstacles"),
    ({"obstacle_type": "crate"}, "obstacle_type"),
    ({"type": "drag_race"}, "type"),
    ({"number_of_obstacle": 3}, "number_of_obstacle"),
    ({"penalty_seconds": -1}, "penalty_seconds"),
])
def test_bad_race_settings_name_the_key(table, key):
    with pytest.raises(ConfigError) as err:
        RaceConfig.from_mapping({"type": "object_avoidance", **table}, where="training.toml [race]")
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith("training.toml [race]:") and key in msg


def test_race_table_of_training_toml(tmp_path):
    from racerlab.model.config import load_training_config, parse_training_config

    path = tmp_path / "training.toml"
    path.write_text('[race]\ntype = "object_avoidance"\nobject_positions = ["0.2,1", "0.5,-1"]\n'
                    'min_distance_between_obstacles = 5\n')
    cfg = load_training_config(path)
    assert cfg.race.object_positions == ((0.2, 1), (0.5, -1)) and cfg.race.num_obstacles == 2
    again = parse_training_config(__import__("tomllib").loads(cfg.to_toml()))
    assert again.race == cfg.race
    path.write_text('[race]\ntype = "object_avoidance"\nobject_positions = ["0.2,3"]\n')
    with pytest.raises(ConfigError, match=r"training.toml \[race\]: object_positions lane"):
        load_training_config(path)
    path.write_text('[race]\nrandomize_obstacle_locations = "yes"\n')
    with pytest.raises(ConfigError, match="randomize_obstacle_locations must be true or false"):
        load_training_config(path)


def test_a_start_near_a_box_moves_to_the_other_lane(aws_track):
    # evenly spaced: the first box is 2 % of the lap (0.46 m) after the start line in the inner lane, so the
    # car starting at the line goes to the outer lane and can drive straight past it
    t = aws_track(TRACK)
    sim = Simulator(t, 1, race=RaceConfig(type="object_avoidance", number_of_obstacles=3))
    q = nearest_on(0.5 * (t.center + t.outer), t.center[0])[0]
    np.testing.assert_allclose([sim.state.x[0], sim.state.y[0]], q, atol=1e-9)
    codes = [sim.step(0.0, 0.5)[0] for _ in range(20)]
    assert 2 not in codes  # never crashed
    sim2 = oa_sim(t, [(0.5, 1)])  # nothing near the start: the centre line
    np.testing.assert_allclose([sim2.state.x[0], sim2.state.y[0]], t.center[0], atol=1e-9)


def test_init_object_avoidance_writes_a_race_and_a_reward_that_reads_objects(tmp_path):
    from racerlab.cli import main
    from racerlab.model.config import load_training_config
    from racerlab.sim.world import World

    assert main(["init", str(tmp_path / "oa"), "--race", "object_avoidance"]) == 0
    cfg = load_training_config(tmp_path / "oa" / "training.toml")
    assert cfg.race.type == "object_avoidance" and cfg.race.num_obstacles == 3
    oa = tmp_path / "oa"
    world = World(cfg.track.names[0], 2, oa / "model_metadata.json", oa / "reward_function.py", race=cfg.race,
                  keep_params=True, seed=0)
    rewards = []
    for _ in range(30):
        codes, r = world.step(np.array([4, 5]))
        rewards += r.tolist()
        if world.done(codes)[0].any():
            world.sim.reset(world.done(codes)[0])
    assert len(world.params[0]["objects_location"]) == 3 and all(x >= 0 for x in rewards)
    from racerlab.reward import load_reward_function

    fn = load_reward_function(tmp_path / "oa" / "reward_function.py")
    base = dict(world.params[0], is_offtrack=False, is_crashed=False, all_wheels_on_track=True, x=0.0, y=0.0,
                distance_from_center=0.0, is_left_of_center=True, closest_objects=[0, 0],
                objects_location=[[1.0, 0.0]], objects_left_of_center=[True])
    # the example reward: with the next box on the left, the right lane line pays most, the box's lane least
    w = base["track_width"]
    right, centre, left = (fn(dict(base, distance_from_center=d, is_left_of_center=side))
                           for d, side in ((0.25 * w, False), (0.0, True), (0.25 * w, True)))
    assert right > centre > left
    # a box just passed (0.3 m behind, on the left) still counts until the car's tail is clear, then the next one
    two = dict(base, closest_objects=[0, 1], objects_location=[[-0.3, 0.0], [3.0, 0.0]],
               objects_left_of_center=[True, False], distance_from_center=0.25 * w, is_left_of_center=False)
    assert fn(two) > fn(dict(two, objects_location=[[-1.0, 0.0], [3.0, 0.0]]))


def test_features_end_with_the_nearest_boxes_ahead_in_the_car_frame(aws_track):
    t = aws_track(TRACK)
    positions = [(0.7, -1), (0.2, 1), (0.45, -1)]
    sim = oa_sim(t, positions)
    assert sim.feature_size == Simulator(t, 1).feature_size + 4
    length = arc_lengths(t.center)[-1]
    m = point_at(t.center, 0.3 * length)
    _, _, heading = nearest_on(t.center, m)
    bx, by = m[0] - 0.14 * math.cos(heading), m[1] - 0.14 * math.sin(heading)
    sim.set_pose(0, bx, by, heading)
    f = sim.features()[0, -4:]
    for k, j in enumerate((2, 0)):  # ahead of 0.3: the box at 0.45, then the one at 0.7
        d = box_pose(t, *positions[j])[0] - (bx, by)
        fwd = d[0] * math.cos(heading) + d[1] * math.sin(heading)
        left = -d[0] * math.sin(heading) + d[1] * math.cos(heading)
        np.testing.assert_allclose(f[2 * k:2 * k + 2], [fwd / 2, left / 2], atol=1e-9)


def test_lidar_sees_the_car_s_own_boxes(aws_track):
    from racerlab.sim.sensors import Lidar
    from racerlab.sim.sensors.geometry import lidar_position, lidar_ray_angles

    t = aws_track(TRACK)
    sim = oa_sim(t, [(0.5, 1)], num_cars=2)
    q, yaw = box_pose(t, 0.5, 1)
    fx, fy = math.cos(yaw), math.sin(yaw)
    lx, ly = -fy, fx
    # car 0: lidar level with the box centre, the box 0.5 m to its left; car 1 far from its box
    sim.set_pose(0, q[0] - lidar_position() * fx - 0.5 * lx, q[1] - lidar_position() * fy - 0.5 * ly, yaw)
    sim.set_pose(1, *point_at(t.center, 0.05 * arc_lengths(t.center)[-1]), yaw)
    lidar = Lidar(sim, noise_sigma_m=0.0)
    r = lidar.scan().astype(float)
    a = lidar_ray_angles()
    side = 0.5 - 0.15  # the box is 0.30 m across: its near face is 0.35 m away
    with np.errstate(divide="ignore"):
        along = side / np.tan(a)
    hits = (np.sin(a) > 0) & (np.abs(along) <= 0.2)
    np.testing.assert_allclose(r[0][hits], side / np.sin(a[hits]), atol=1e-6)
    assert (r[0][~hits] == 1.0).all() and hits.sum() >= 10
    assert (r[1] == 1.0).all()  # car 1 does not see car 0's box


def test_evaluation_crash_restarts_behind_the_box_in_the_other_lane(aws_track):
    from racerlab.evaluate.rules import RaceRules, pause_steps
    from racerlab.evaluate.runner import run_evaluation
    from racerlab.model import ContinuousActions, ModelMetadata
    from racerlab.sim import World
    from racerlab.sim.pursuit import PurePursuit

    t = aws_track(TRACK)
    meta = ModelMetadata(ContinuousActions(-30.0, 30.0, 0.5, 4.0), ("FEATURES",), "MLP")
    w = World(t, 1, meta, None, "features", max_episode_steps=100_000, seed=0,
              race={"type": "object_avoidance", "object_positions": [[0.5, 1]]})
    pp = PurePursuit.on_centre_line(t, speed=1.0)

    def policy(obs):  # the centre line passes 0.27 m from the box: a crash
        steer, v = pp(w.sim)
        return np.stack([steer / 30.0, (v - 0.5) / 1.75 - 1.0], axis=1)

    run = run_evaluation(w, policy, RaceRules(trials=1, collision_penalty=1.0, max_resets=1))
    tr, x = run.trace, run.extra
    crash = np.flatnonzero(tr["episode_status"] == "crashed")
    assert crash.size == 2 and run.laps[0].status == "crashed" and run.laps[0].counts["crashed"] == 2
    i = crash[0]
    assert tr["obstacle_crash_counter"][i] == 1 and tr["obstacle_crash_counter"][i - 1] == 0
    assert tr["pause_duration"][i] == 1.0
    pause = np.arange(i + 1, i + 1 + pause_steps(1.0))
    assert np.all(tr["episode_status"][pause] == "pause") and np.all(tr["obstacle_crash_counter"][pause] == 1)
    # put back 1 m of centre line behind the box, on the outer lane (the box is in the inner one)
    box = box_pose(t, 0.5, 1)[0]
    s_box = nearest_on(t.center, box)[1]
    want, _, _ = nearest_on(0.5 * (t.center + t.outer), point_at(t.center, s_box - 1.0))
    np.testing.assert_allclose([x["base_x"][pause[0]], x["base_y"][pause[0]]], want, atol=1e-9)
    # progress is measured there: the model point, 0.14 m ahead of that base, from the start line
    length = arc_lengths(t.center)[-1]
    assert tr["progress"][pause[0]] == pytest.approx(100.0 * (s_box - 1.0 + 0.14) / length, abs=0.05)


def lane_at_centre(track, lane, d):
    """AWS's bot path: the lane line's points keyed by the centre-line arc of their projection (brute force),
    linear between them, at centre-line distance d (wrapping around the lap)."""
    line = 0.5 * (track.center + (track.inner if lane == 1 else track.outer))
    length = arc_lengths(track.center)[-1]
    u = np.array([nearest_on(track.center, p)[1] for p in line])
    u, first = np.unique(np.mod(u, length), return_index=True)
    pts = line[first]
    return np.array([np.interp(d, u, pts[:, 0], period=length), np.interp(d, u, pts[:, 1], period=length)])


def h2b_sim(track, **kw):
    return Simulator(track, 1, race=RaceConfig(type="head_to_bot", **kw))


def test_bot_cars_drive_their_lane_by_centre_line_distance(aws_track):
    t = aws_track(TRACK)
    sim = h2b_sim(t, number_of_bot_cars=2, bot_car_speed=0.6)
    length = arc_lengths(t.center)[-1]
    assert sim.objects.lane[0].tolist() == [1, -1]  # at 2 m (min_distance_between_bot_cars) and L - 1 m
    np.testing.assert_allclose(sim.objects.xy[0, 0], lane_at_centre(t, 1, 2.0), atol=1e-9)
    np.testing.assert_allclose(sim.objects.xy[0, 1], lane_at_centre(t, -1, length - 1.0), atol=1e-9)
    sim.set_pose(0, *point_at(t.center, 0.5 * length), 0.0)  # the agent out of the way
    for _ in range(30):
        sim.step(0.0, 0.1)
    elapsed = 30 / 15
    np.testing.assert_allclose(sim.objects.xy[0, 0], lane_at_centre(t, 1, 2.0 + 0.6 * elapsed), atol=1e-9)
    # the second bot crossed the start line: its centre distance wraps around the lap
    np.testing.assert_allclose(sim.objects.xy[0, 1], lane_at_centre(t, -1, 0.6 * elapsed - 1.0), atol=1e-9)
    p = ParamsBuilder(sim).build()[0]
    assert p["objects_speed"] == [0.6, 0.6]
    ahead = lane_at_centre(t, 1, 2.0 + 0.6 * elapsed + 0.05) - lane_at_centre(t, 1, 2.0 + 0.6 * elapsed - 0.05)
    assert p["objects_heading"][0] == pytest.approx(math.atan2(ahead[1], ahead[0]), abs=1e-9)  # radians


def test_random_bot_placement_keeps_the_gap_in_metres(aws_track):
    t = aws_track(TRACK)
    length = arc_lengths(t.center)[-1]
    sim = Simulator(t, 4, race=RaceConfig(type="head_to_bot", number_of_bot_cars=4, min_distance_between_bot_cars=3.0,
                                          randomize_bot_car_locations=True), seed=3)
    d = sim.objects.d0
    assert (np.diff(d, axis=1) >= 3.0 - 1e-9).all() and (d[:, 0] >= 3.0).all() and (d[:, -1] <= length - 1.0).all()
    assert not np.allclose(d[0], np.linspace(3.0, length - 1.0, 4))  # re-drawn, not evenly spaced
    assert set(np.unique(sim.objects.lane)) <= {1, -1}
    before = d.copy()
    sim.reset()
    assert not np.allclose(sim.objects.d0, before)  # a new layout at every reset


def test_lane_change_blends_between_the_lane_lines(aws_track):
    t = aws_track(TRACK)
    length = arc_lengths(t.center)[-1]
    # a change every 1 s (U(1, 1)) over 1 m at 0.5 m/s: 2 s long, starting 1 s after the bots start driving
    sim = h2b_sim(t, number_of_bot_cars=1, bot_car_speed=0.5, is_lane_change=True, lower_lane_change_time=1.0,
                  upper_lane_change_time=1.0, lane_change_distance=1.0)
    sim.set_pose(0, *point_at(t.center, 0.5 * length), 0.0)
    dt = 1 / 15
    start, end = dt + 1.0, dt + 3.0  # drawn on the first step of the bots' clock
    seen = []
    for k in range(1, 15 * 4):
        sim.step(0.0, 0.1)
        clock = k * dt
        d = 2.0 + 0.5 * clock
        a = min(max((clock - start) / (end - start), 0.0), 1.0)
        w = a * a * (3 - 2 * a)
        want = (1 - w) * lane_at_centre(t, 1, d) + w * lane_at_centre(t, -1, d)
        np.testing.assert_allclose(sim.objects.xy[0, 0], want, atol=1e-9)
        seen.append(w)
    assert seen[0] == 0.0 and seen[-1] == 1.0 and 0.4 < seen[29] < 0.6  # inner lane, halfway, outer lane
    assert sim.objects.lane[0, 0] == -1  # the change ended: the bot's lane is the outer one


def test_bot_that_rear_ends_the_agent_pauses_and_is_not_the_agents_crash(aws_track):
    t = aws_track(TRACK)
    race = dict(number_of_bot_cars=2, bot_car_speed=0.6, penalty_seconds=2.0)

    def judged(offset):
        """Agent aligned with bot 0, `offset` m ahead (+) or behind (-) of it, the two overlapping."""
        s2 = h2b_sim(t, **race)
        bx, by = s2.objects.xy[0, 0]
        byaw = s2.objects.yaw[0, 0]
        s2.set_pose(0, bx + offset * math.cos(byaw), by + offset * math.sin(byaw), byaw)
        s2.step(0.0, 0.1)
        return s2, s2.status_names(s2.step(0.0, 0.1))[0]

    sim, status = judged(-0.2)
    assert status == "crashed"  # the agent's nose in the bot's tail
    assert sim.objects.pause_left[0] == 0.0
    sim, status = judged(0.2)
    assert status == "in_progress"  # the bot's nose in the agent's tail: not the agent's crash ...
    # the bots stop for penalty_seconds, counted from this step: 30 steps of 1/15 s with no bot clock
    assert sim.objects.pause_left[0] == pytest.approx(2.0 - 1 / 15)
    held = sim.objects.xy[0].copy()
    clock = sim.objects.clock[0]
    for _ in range(29):
        sim.step(0.0, 0.0)
        np.testing.assert_allclose(sim.objects.xy[0], held, atol=1e-12)
    sim.step(0.0, 0.0)
    assert sim.objects.clock[0] == pytest.approx(clock + 1 / 15)  # then they drive on from where they stopped
    np.testing.assert_allclose(sim.objects.xy[0, 0], lane_at_centre(t, 1, 2.0 + 0.6 * 2 / 15), atol=1e-9)


def test_evaluation_bot_crash_holds_the_car_where_it_is(aws_track):
    from racerlab.evaluate.rules import RaceRules, pause_steps
    from racerlab.evaluate.runner import run_evaluation
    from racerlab.model import ContinuousActions, ModelMetadata
    from racerlab.sim import World
    from racerlab.sim.pursuit import PurePursuit

    t = aws_track(TRACK)
    meta = ModelMetadata(ContinuousActions(-30.0, 30.0, 0.5, 4.0), ("FEATURES",), "MLP")
    w = World(t, 1, meta, None, "features", max_episode_steps=100_000, seed=0,
              race={"type": "head_to_bot", "number_of_bot_cars": 1, "bot_car_speed": 0.1})
    pp = PurePursuit(0.5 * (t.center + t.inner), speed=1.5)

    def policy(obs):  # 1.5 m/s on the inner lane catches the 0.1 m/s bot in that lane 2 m ahead
        steer, v = pp(w.sim)
        return np.stack([steer / 30.0, (v - 0.5) / 1.75 - 1.0], axis=1)

    run = run_evaluation(w, policy, RaceRules(trials=1, collision_penalty=1.0, max_resets=1))
    tr, x = run.trace, run.extra
    crash = np.flatnonzero(tr["episode_status"] == "crashed")
    assert crash.size >= 1
    i = crash[0]
    pause = np.arange(i + 1, i + 1 + pause_steps(1.0))
    assert np.all(tr["episode_status"][pause] == "pause") and np.all(tr["obstacle_crash_counter"] == 0)
    # held where it was after the crash step (no restart behind the bot), the bot driving on
    np.testing.assert_allclose(x["base_x"][pause], x["base_x"][i], atol=1e-12)
    np.testing.assert_allclose(x["base_y"][pause], x["base_y"][i], atol=1e-12)
    assert tr["progress"][pause[0]] == pytest.approx(tr["progress"][i], abs=1.0)


def h2m_pair(track, gap):
    """Two head-to-model cars on a straight track's centre line, car 1 `gap` m (base to base) behind car 0."""
    sim = Simulator(track, 2, race=RaceConfig(type="head_to_model"))
    x0, y0 = point_at(track.center, 0.5 * arc_lengths(track.center)[-1])
    yaw = float(np.ravel(track.heading_at(0.0))[0])  # a straight track: one heading
    sim.set_pose(0, x0, y0, yaw, start_ndist=0.0)
    sim.set_pose(1, x0 - gap * math.cos(yaw), y0 - gap * math.sin(yaw), yaw, start_ndist=0.0)
    return sim, (x0, y0, yaw)


def test_head_to_model_cars_are_each_others_object(aws_track):
    t = aws_track("Straight_track")
    sim, (x0, y0, yaw) = h2m_pair(t, 0.5)
    np.testing.assert_allclose(sim.objects.xy[0, 0], [x0 - 0.5 * math.cos(yaw), y0 - 0.5 * math.sin(yaw)], atol=1e-12)
    np.testing.assert_allclose(sim.objects.xy[1, 0], [x0, y0], atol=1e-12)
    p = ParamsBuilder(sim).build()
    assert p[0]["objects_location"] == [list(sim.objects.xy[0, 0])]
    assert p[0]["objects_heading"] == [0.0] and p[0]["objects_speed"] == [0.0]  # AWS fills these for bots only
    # car 0's lidar sees car 1 behind it: the nearest rays (±2.4° off straight back) meet car 1's nose,
    # 0.5 m - 0.16176 m (half the car) + 0.029 m (the lidar sits ahead of the base) away
    from racerlab.sim.sensors.lidar import LidarObservation

    ranges = LidarObservation(sim)()
    want = (0.5 - 0.5 * 0.32352 + 0.029) / math.cos(math.radians(300 / 63 / 2))
    assert ranges[0].min() == pytest.approx(want, abs=0.04)
    assert ranges[1].min() == 1.0  # car 0 is ahead of car 1, in the lidar's 60° gap


def test_head_to_model_crash_is_the_car_behind(aws_track):
    t = aws_track("Straight_track")
    sim, _ = h2m_pair(t, 0.25)  # car 1's nose 0.07 m into car 0's tail
    sim.step(0.0, 0.0)
    assert sim.status_names(sim.step(0.0, 0.0)) == ["in_progress", "crashed"]
    sim, _ = h2m_pair(t, 0.35)  # 0.03 m apart: no crash
    sim.step(0.0, 0.0)
    assert sim.status_names(sim.step(0.0, 0.0)) == ["in_progress", "in_progress"]
    with pytest.raises(ConfigError, match="even number of cars"):
        Simulator(t, 3, race=RaceConfig(type="head_to_model"))


def test_head_to_model_evaluation_crash_holds_the_car_behind_in_place(aws_track):
    from racerlab.evaluate.rules import RaceRules, pause_steps
    from racerlab.evaluate.runner import run_head_to_model
    from racerlab.model import ContinuousActions, ModelMetadata
    from racerlab.sim import World
    from racerlab.sim.pursuit import PurePursuit

    t = aws_track(TRACK)
    meta = ModelMetadata(ContinuousActions(-30.0, 30.0, 0.5, 4.0), ("LIDAR",), "MLP")
    # a car that follows the lane exactly (no delay, lag or slip): the rules are under test, and the fast car must
    # stay behind the slow one in the lane rather than swing out beside it
    exact = CarParams(delay_steps=0.0, steer_tau_s=0.0, yaw_gain=1.0, ground_factor=1.0)
    a = World(t, 2, meta, None, "lidar", max_episode_steps=100_000, seed=0, race={"type": "head_to_model"},
              car=exact)
    b = World(None, 2, meta, None, "lidar", sim=a.sim)
    inner = 0.5 * (t.center + t.inner)
    slow, fast = PurePursuit(inner, speed=0.5), PurePursuit(inner, speed=2.5)

    def driver(pp, car):
        def policy(obs):  # both follow the inner lane: the fast car laps the slow one and runs into it
            steer, v = pp(a.sim)
            return np.stack([steer[car:car + 1] / 30.0, (v[car:car + 1] - 0.5) / 1.75 - 1.0], axis=1)
        return policy

    runs = run_head_to_model([a, b], [driver(slow, 0), driver(fast, 1)],
                             RaceRules(trials=2, collision_penalty=1.0, max_resets=2))
    tr, x = runs[1].trace, runs[1].extra
    crash = np.flatnonzero(tr["episode_status"] == "crashed")
    assert crash.size >= 1 and (runs[0].trace["episode_status"] == "crashed").sum() == 0  # the car behind
    i = crash[0]
    pause = np.arange(i + 1, i + 1 + pause_steps(1.0))
    assert np.all(tr["episode_status"][pause] == "pause") and np.all(tr["obstacle_crash_counter"] == 0)
    np.testing.assert_allclose(x["base_x"][pause], x["base_x"][i], atol=1e-12)  # held where it was
    np.testing.assert_allclose(x["base_y"][pause], x["base_y"][i], atol=1e-12)
    # one clock: the slow car drove on while the fast one was held (29 steps at up to 0.5 m/s, slower in the bend)
    slow_x = runs[0].extra
    assert runs[0].trace["tstamp"][pause[-1]] == tr["tstamp"][pause[-1]]
    moved = math.hypot(slow_x["base_x"][pause[-1]] - slow_x["base_x"][pause[0]],
                       slow_x["base_y"][pause[-1]] - slow_x["base_y"][pause[0]])
    assert 0.2 < moved <= 0.5 * 29 / 15 * 1.05
    assert runs[1].laps[-1].status == "crashed" and runs[1].laps[-1].counts["crashed"] == 3  # resets used up


def test_crashed_ranks_before_off_track(aws_track):
    """A car facing a box across the outer border: no wheel on the road, a front corner inside the box's
    footprint. AWS's status order (lap_complete, crashed, off_track, ...) makes it `crashed`."""
    t = aws_track(TRACK)
    sim = oa_sim(t, [(0.02, -1)])
    box = sim.objects.xy[0, 0]
    centre = nearest_on(t.center, box)[0]
    n = (box - centre) / np.hypot(*(box - centre))  # outwards, across the lane
    base = box + 0.355 * n  # front corners 0.355 - 0.16176 = 0.193 m from the box centre: inside its 0.2 m half-width
    yaw = math.atan2(-n[1], -n[0])  # facing the box
    fwd, left = -n, np.array([n[1], -n[0]])
    wheels = [base + ax * fwd + side * left for ax in (-0.081663, 0.082311) for side in (0.08, -0.08)]
    assert not t.contains(np.array(wheels)).any()  # every wheel centre off the road
    for race, want in ((sim, "crashed"), (Simulator(t, 1), "off_track")):
        race.set_pose(0, *base, yaw)
        race.step(0.0, 0.1)
        assert race.status_names(race.step(0.0, 0.1)) == [want]
