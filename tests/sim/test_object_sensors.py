"""The camera, stereo and lidar see the race's objects: boxes and bot cars, nearest surface first."""

from __future__ import annotations

import math

import numpy as np
import pytest

from racerlab.sim import Simulator
from racerlab.sim.objects import RaceConfig
from racerlab.sim.sensors import Camera, Lidar
from racerlab.sim.sensors.geometry import CAMERA_HFOV_RAD, CAMERA_PITCH_RAD, camera_position
from racerlab.sim.sensors.look import LOOKS, TrackLook
from racerlab.sim.sensors.solids import AMBIENT, BOT_CAR_HEIGHT_M, DIFFUSE, LIGHT_DIR
from racerlab.track import from_array

H, W = 120, 160
F_PX = 0.5 * W / math.tan(0.5 * CAMERA_HFOV_RAD)
CAM_X, CAM_Z = camera_position()[0], TrackLook().camera_z  # the default (AWS) look's camera height, 0.163 m
BOX_L, BOX_W, BOX_H = 0.40, 0.30, 0.25  # AWS box_obstacle model


@pytest.fixture(scope="module")
def straight():
    """A straight road along +x from x = -5 to 40, 1 m wide, centred on y = 0."""
    x = np.linspace(-5.0, 40.0, 91)
    z = np.zeros_like(x)
    return from_array(np.column_stack([x, z, x, z + 0.5, x, z - 0.5]), name="straight")


def box_sim(track, boxes, cars=1):
    """A simulator whose cars each have these boxes (x, y, yaw), set by hand; the cars at the origin, heading +x."""
    positions = [[0.1 + 0.1 * k, 1] for k in range(len(boxes))]
    sim = Simulator(track, cars, seed=0, race=RaceConfig(type="object_avoidance", object_positions=positions))
    sim.reset()
    for i in range(cars):
        sim.set_pose(i, 0.0, 0.0, 0.0)  # (places the car's boxes again: set them after)
    sim.objects.xy[:] = np.asarray(boxes, dtype=float)[None, :, :2]
    sim.objects.yaw[:] = np.asarray(boxes, dtype=float)[None, :, 2]
    return sim


def row_of(elevation_rad):
    """Image row coordinate (0 = top edge) of a direction `elevation_rad` above the horizontal."""
    return 0.5 * H - F_PX * math.tan(elevation_rad + CAMERA_PITCH_RAD)


def face_grey(nx, ny):
    """The grey of a box side whose outward normal is (nx, ny) in the world (half-Lambert under LIGHT_DIR)."""
    g = TrackLook().object_grey()
    return g * (AMBIENT + DIFFUSE * 0.5 * (1.0 + nx * LIGHT_DIR[0] + ny * LIGHT_DIR[1]))


def test_a_box_ahead_covers_the_rows_and_columns_the_camera_model_predicts(straight):
    ahead = 2.0  # box centre, m ahead of the base; its near face is 1.8 m ahead, 1.8 - CAM_X from the camera
    sim = box_sim(straight, [(ahead, 0.0, 0.0)])
    # the classic look's flat dark road: the AWS look's grainy asphalt comes within 20 grey levels of the box's face
    img = Camera(sim, look=LOOKS["classic"]).render()[0, :, :, 0].astype(float)
    d = ahead - 0.5 * BOX_L - CAM_X
    cz = LOOKS["classic"].camera_z  # the URDF's 0.130 m
    top = row_of(math.atan2(BOX_H - cz, d))  # the face's top edge, above the camera (the top face is hidden)
    bottom = row_of(math.atan2(-cz, d))
    assert 14 < top < 18 and 35 < bottom < 38  # 0.12 m above and 0.13 m below the camera, 1.65 m away
    face = face_grey(-1.0, 0.0)  # we look at the box's back (-x) face
    col = img[:, W // 2]
    inside = [r for r in range(H) if top < r + 0.5 < bottom]
    assert np.all(np.abs(col[inside] - face) <= 1.0)
    assert abs(col[math.floor(top) - 1] - face) > 20 and abs(col[math.ceil(bottom)] - face) > 20
    # columns at the row through the face's middle: the face spans +-0.15 m across at depth d along the view
    r = int(0.5 * (top + bottom))
    elev = math.atan2(0.5 * H - (r + 0.5), F_PX) - CAMERA_PITCH_RAD
    depth = d * math.cos(CAMERA_PITCH_RAD + elev) / math.cos(elev)  # along the optical axis
    half = F_PX * 0.5 * BOX_W / depth
    seen = np.flatnonzero(np.abs(img[r] - face) <= 1.0)
    assert seen.min() == math.ceil(0.5 * W - half - 0.5)
    assert seen.max() == math.floor(0.5 * W + half - 0.5)


def test_a_box_behind_another_is_hidden(straight):
    near, far = (1.5, 0.0, 0.0), (3.0, 0.0, 0.0)
    both = Camera(box_sim(straight, [near, far])).render()[0]
    alone = Camera(box_sim(straight, [near, (-20.0, 8.0, 0.0)])).render()[0]  # the second box behind the car
    far_only = Camera(box_sim(straight, [(-20.0, 8.0, 0.0), far])).render()[0]
    assert np.array_equal(both, alone)
    assert (far_only != alone).sum() > 100  # the far box alone is visible, so hiding it was the near box's doing
    # a box in front of the far one (nearer, lower in the picture) hides it only where they overlap
    offset = Camera(box_sim(straight, [(1.5, 0.35, 0.0), far])).render()[0]
    assert (offset != alone).sum() > 100


def test_the_box_hides_the_road_behind_it_not_in_front(straight):
    sim = box_sim(straight, [(2.0, 0.0, 0.0)])
    img = Camera(sim).render()[0, :, :, 0].astype(float)
    empty = Camera(box_sim(straight, [(-20.0, 8.0, 0.0)])).render()[0, :, :, 0].astype(float)
    bottom = row_of(math.atan2(-CAM_Z, 2.0 - 0.5 * BOX_L - CAM_X))
    below = slice(math.ceil(bottom) + 1, H)
    assert np.array_equal(img[below], empty[below])  # the road between the car and the box
    assert (img[: math.floor(bottom)] != empty[: math.floor(bottom)]).any()


def test_box_sides_are_shaded_and_far_boxes_fade_into_haze_where_the_look_has_haze(straight):
    # turned 45 degrees, the box shows the camera two sides: -x (normal (-1, -1)/sqrt 2) and +y (normal (-1, 1)/sqrt 2)
    q = math.sqrt(0.5)
    row = Camera(box_sim(straight, [(2.0, 0.0, math.pi / 4)])).render()[0, 30, :, 0].astype(float)  # mid-box
    for normal in ((-q, -q), (-q, q)):
        assert np.abs(row - face_grey(*normal)).min() <= 1.0
    assert abs(face_grey(-q, -q) - face_grey(-q, q)) > 10
    sim = box_sim(straight, [(20.0, 0.0, 0.0)])
    far = Camera(sim, look=LOOKS["classic"]).render()[0, :, :, 0].astype(float)
    haze = LOOKS["classic"].grey()[6]
    fade = ((20.0 - 0.2 - CAM_X - 4.0) / 26.0) ** 0.7  # the classic look's haze ramp, 4 to 30 m
    expected = face_grey(-1.0, 0.0) * (1.0 - fade) + haze * fade
    r = int(0.5 * (row_of(math.atan2(BOX_H - CAM_Z, 19.7)) + row_of(math.atan2(-CAM_Z, 19.7))))
    assert far[r, W // 2] == pytest.approx(expected, abs=1.5)
    # the AWS look has no haze: the far box keeps its grey
    assert Camera(sim).render()[0, r, W // 2, 0] == pytest.approx(face_grey(-1.0, 0.0), abs=1.5)


def _run_at_centre(mask):
    """The columns of the unbroken run of `mask` through the image's middle column (a field ramp of the same grey
    beside the box, where the wall meets the field, is left out)."""
    lo = hi = W // 2
    while lo > 0 and mask[lo - 1]:
        lo -= 1
    while hi < W - 1 and mask[hi + 1]:
        hi += 1
    return np.arange(lo, hi + 1)


def test_stereo_disparity_matches_the_baseline(straight):
    ahead = 1.6
    sim = box_sim(straight, [(ahead, 0.0, 0.0)])
    st = Camera(sim, stereo=True).render()[0].astype(float)
    d = ahead - 0.5 * BOX_L - CAM_X
    top = row_of(math.atan2(BOX_H - CAM_Z, d))
    bottom = row_of(math.atan2(-CAM_Z, d))
    r = int(0.5 * (top + bottom))
    elev = math.atan2(0.5 * H - (r + 0.5), F_PX) - CAMERA_PITCH_RAD
    depth = d * math.cos(CAMERA_PITCH_RAD + elev) / math.cos(elev)
    face = face_grey(-1.0, 0.0)
    left, right = (_run_at_centre(np.abs(st[r, :, e] - face) <= 1.0) for e in range(2))
    disparity = F_PX * 0.06 / depth  # the left eye sees the box further right
    assert 0.5 * ((left.min() - right.min()) + (left.max() - right.max())) == pytest.approx(disparity, abs=1.0)
    assert left.min() > right.min()


def test_each_car_sees_only_its_own_boxes(straight):
    sim = box_sim(straight, [(2.0, 0.0, 0.0)], cars=2)
    sim.objects.xy[1] = [[-20.0, 8.0]]  # car 1's box is out of its view
    f = Camera(sim).render()
    empty = Camera(box_sim(straight, [(-20.0, 8.0, 0.0)])).render()[0]
    assert np.array_equal(f[1], empty) and not np.array_equal(f[0], empty)


def test_boxes_move_with_the_object_set(straight):
    sim = box_sim(straight, [(2.0, 0.0, 0.0)])
    cam = Camera(sim)
    a = cam.render()[0].copy()
    sim.objects.xy[0, 0] = [2.0, 0.3]
    b = cam.render()[0]
    assert not np.array_equal(a, b)


def test_a_bot_car_is_lower_and_darker_than_a_box(straight):
    sim = box_sim(straight, [(2.0, 0.0, 0.0)])
    sim.objects.bots = True  # a head-to-bot race's object set: car-sized objects
    sim.objects.box_size_m = np.array([0.32352, 0.1961])
    img = Camera(sim).render()[0, :, :, 0].astype(float)
    d = 2.0 - 0.5 * 0.32352 - CAM_X
    top = row_of(math.atan2(BOT_CAR_HEIGHT_M - CAM_Z, d))
    grey = TrackLook().object_grey(bot_car=True) * (AMBIENT + DIFFUSE * 0.5 * (1.0 - LIGHT_DIR[0]))
    col = img[:, W // 2]
    assert abs(col[math.ceil(top)] - grey) <= 1.0 and abs(col[math.floor(top) - 1] - grey) > 10
    assert grey < face_grey(-1.0, 0.0) - 30


def test_lidar_hits_the_near_face_of_a_box_beside_the_car(straight):
    # the lidar's ray 15 looks left-behind; a box straight left at 0.6 m: the ray along +y hits y = 0.6 - 0.15
    sim = box_sim(straight, [(0.029, 0.6, 0.0)])
    lidar = Lidar(sim, noise_sigma_m=0.0)
    r = lidar.scan()[0]
    angles = np.degrees(np.arctan2(np.sin(lidar.angles), np.cos(lidar.angles)))
    k = int(np.argmin(np.abs(angles - 90.0)))
    expected = 0.45 / math.cos(math.radians(angles[k] - 90.0))
    assert r[k] == pytest.approx(expected, abs=1e-6)
    assert r[int(np.argmin(np.abs(angles + 90.0)))] == pytest.approx(1.0)  # nothing on the right


def _reference_ranges(origin, angles, rects, reach):
    """Ray-rectangle ranges by the slab method (independent of the lidar's side-by-side casting): origin (2,),
    world ray angles (R,), rectangles (M, 5) [x, y, yaw, length, width]; 0 from inside; inf beyond reach."""
    best = np.full(angles.size, np.inf)
    d = np.stack([np.cos(angles), np.sin(angles)], -1)
    for x, y, yaw, length, width in rects:
        c, s = math.cos(yaw), math.sin(yaw)
        rel = origin - (x, y)
        o = np.array([c * rel[0] + s * rel[1], -s * rel[0] + c * rel[1]])  # the origin in the box's frame
        du = c * d[:, 0] + s * d[:, 1]
        dv = -s * d[:, 0] + c * d[:, 1]
        enter = np.zeros(angles.size)
        leave = np.full(angles.size, np.inf)
        for oc, dc, half in ((o[0], du, 0.5 * length), (o[1], dv, 0.5 * width)):
            with np.errstate(divide="ignore", invalid="ignore"):
                t1, t2 = (-half - oc) / dc, (half - oc) / dc
            parallel = np.abs(dc) < 1e-12
            inside = abs(oc) <= half
            enter = np.maximum(enter, np.where(parallel, np.where(inside, 0.0, np.inf), np.minimum(t1, t2)))
            leave = np.minimum(leave, np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2)))
        best = np.minimum(best, np.where(enter <= leave, enter, np.inf))
    return np.where(best <= reach, best, np.inf)


def test_lidar_ranges_with_boxes_match_a_reference_ray_cast(aws_track):
    """Many random poses around each car's own randomly placed boxes on a real track, and a few shared rectangles
    seen by some cars: every ray equals an independent slab-method cast (clipped as AWS clips)."""
    from racerlab.sim.sensors.geometry import lidar_position

    t = aws_track("reInvent2019_track")
    n = 240
    race = RaceConfig(type="object_avoidance", number_of_obstacles=6, randomize_obstacle_locations=True)
    sim = Simulator(t, n, seed=4, race=race)
    rng = np.random.default_rng(11)
    extra = np.array([[*sim.objects.xy[0, 0] + (0.3, -0.2), 0.7, 0.2, 0.6], [2.0, 1.0, -1.1, 0.5, 0.5],
                      [*t.center[10], 0.0, 0.05, 0.05]])
    lidar = Lidar(sim, noise_sigma_m=0.0)
    lidar.set_objects(extra, visible=rng.random((n, 3)) < 0.5)
    for i in range(n):
        m = rng.integers(6)
        r, a, yaw = rng.uniform(0.0, 1.4), rng.uniform(-math.pi, math.pi), rng.uniform(-math.pi, math.pi)
        if i < 20:  # on top of the first extra rectangle, or on a box's edge line
            ox, oy = extra[0, :2] + rng.normal(0.0, 0.2, 2)
        else:
            ox, oy = sim.objects.xy[i, m] + r * np.array([math.cos(a), math.sin(a)])
        sim.relocate(i, ox - lidar_position() * math.cos(yaw), oy - lidar_position() * math.sin(yaw), yaw)
    got = lidar.scan().astype(float)
    box_l, box_w = sim.objects.box_size_m
    hit_rays = 0
    for i in range(n):
        yaw = sim.state.yaw[i]
        origin = np.array([sim.state.x[i], sim.state.y[i]]) + lidar_position() * np.array([math.cos(yaw),
                                                                                          math.sin(yaw)])
        rects = np.column_stack([sim.objects.xy[i], sim.objects.yaw[i], np.full(6, box_l), np.full(6, box_w)])
        rects = np.vstack([rects, extra[lidar.visible[i]]])
        ref = _reference_ranges(origin, yaw + lidar.angles, rects, lidar.reach_m)
        want = np.where(np.isfinite(ref), np.clip(ref, 0.15, 1.0), 1.0)
        np.testing.assert_allclose(got[i], want, atol=1e-6, err_msg=f"car {i}")
        hit_rays += np.isfinite(ref).sum()
    assert hit_rays > 10 * n  # most poses see a box close by


def test_copied_layouts_equal_placing_each_car(aws_track):
    """Fixed and evenly spaced layouts are placed once per direction and copied: the same arrays and params."""
    from racerlab.sim.objects import ObjectSet

    track = aws_track("reInvent2019_track")
    race = RaceConfig(type="object_avoidance", number_of_obstacles=4)
    fast = ObjectSet(race, track, track.reverse(), 3, np.random.default_rng(0))
    slow = ObjectSet(race, track, track.reverse(), 3, np.random.default_rng(0))
    slow._layouts = None
    rev = np.array([False, True, False])
    fast.place([0, 1, 2], rev)
    slow.place([0, 1, 2], rev)
    for name in ("xy", "yaw", "arc", "dfc", "left", "lane", "order", "rev"):
        assert np.array_equal(getattr(fast, name), getattr(slow, name)), name
    assert fast._lists == slow._lists
    assert not np.array_equal(fast.xy[0], fast.xy[1])  # the reversed direction has its own layout


def test_sim_view_draws_a_race_s_boxes(tmp_path, capsys):
    from racerlab.cli import main
    from racerlab.sim.sensors.view import BOX_COLOR, sensor_view
    from racerlab.track import load

    out = tmp_path / "view.png"
    assert main(["sim", "view", "lab_technical", "--out", str(out), "--cars", "2", "--object-positions",
                 "0.1,1;0.6,-1"]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and "wrote" in capsys.readouterr().out
    fig = sensor_view(load("lab_technical"), 2, race={"type": "object_avoidance", "object_positions": ["0.1,1"]})
    top, lidar = fig.axes[0], fig.axes[2]
    boxes = [p for p in top.patches if p.get_facecolor()[:3] == pytest.approx([0xC8 / 255, 0xA0 / 255, 0x6E / 255])]
    assert len(boxes) == 2 and BOX_COLOR == "#c8a06e"  # car 1's and car 2's box, at the same place
    assert "boxes per car: 1" in fig._suptitle.get_text() and lidar.patches


def bot_sim(track, bots):
    """`box_sim` with car-shaped objects (a head-to-bot race's object set)."""
    sim = box_sim(track, bots)
    sim.objects.bots = True
    sim.objects.box_size_m = np.array([0.32352, 0.1961])
    return sim


def test_a_bot_car_stands_on_wheels_with_the_road_showing_under_its_body(straight):
    from racerlab.sim.sensors.solids import BOT_CAR_PARTS

    sim = bot_sim(straight, [(2.0, 0.0, 0.0)])
    img = Camera(sim).render()[0, :, :, 0].astype(float)
    empty = Camera(box_sim(straight, [(-20.0, 8.0, 0.0)])).render()[0, :, :, 0].astype(float)
    body, wheel = BOT_CAR_PARTS[0], BOT_CAR_PARTS[4]  # the body, the rear right wheel
    # under the body's rear edge (0.017 m up), straight ahead between the rear wheels: the road, as without the car
    d_rear = 2.0 - body[2] - CAM_X
    r = int(row_of(math.atan2(0.5 * body[4] - CAM_Z, d_rear)))
    assert abs(img[r, W // 2] - empty[r, W // 2]) <= 1.0
    # the rear right wheel's back face (0.03 m up), dark, where the pinhole model puts it
    d_wheel = 2.0 + wheel[0] - wheel[2] - CAM_X
    rw = int(row_of(math.atan2(0.5 * wheel[5] - CAM_Z, d_wheel)))
    cw = int(0.5 * W - F_PX * wheel[1] / d_wheel)
    tyre = TrackLook().material_grey("tyre") * (AMBIENT + DIFFUSE * 0.5 * (1.0 - LIGHT_DIR[0]))
    assert abs(img[rw, cw] - tyre) <= 1.0 and img[rw, cw] < empty[rw, cw] - 5
    # a head-to-bot race's crash footprint stays the car's rectangle whatever is drawn
    bots = Simulator(straight, 1, seed=0, race=RaceConfig(type="head_to_bot", number_of_bot_cars=1))
    assert bots.objects.half == pytest.approx((0.16176, 0.09805))


def test_domain_randomization_colours_each_box_and_each_bot_part_anew_every_episode(straight):
    from racerlab.sim.sensors.look import DomainRandomization

    for sim, parts in ((box_sim(straight, [(2.0, 0.3, 0.0), (3.0, -0.3, 0.0)], cars=2), 2),
                       (bot_sim(straight, [(2.0, 0.3, 0.0), (3.0, -0.3, 0.0)]), 10)):
        plain = Camera(sim).solids.grey.copy()
        assert plain.shape[1] == parts
        assert np.unique(np.round(plain[0], 6)).size == (1 if parts == 2 else 2)  # box / body and tyre colours
        cam = Camera(sim, randomization=DomainRandomization())
        first = cam.render()
        grey = cam.solids.grey.copy()
        assert np.unique(np.round(grey, 6)).size == grey.size  # every part of every car its own colour
        assert (grey >= 0).all() and (grey <= 255 * 1.6).all()  # at most a bright channel over a dim neutral
        sim.step(0.0, 0.5)  # the prepare step: the episode has begun
        cam.render()
        np.testing.assert_array_equal(cam.solids.grey, grey)  # the same colours all episode long
        sim.set_pose(0, 0.0, 0.0, 0.0)  # a new episode for car 0: new colours for its objects only
        sim.objects.xy[0] = [[2.0, 0.3], [3.0, -0.3]]
        sim.objects.yaw[0] = 0.0
        cam.render()
        assert not np.isin(cam.solids.grey[0], grey[0]).any()
        if sim.num_cars > 1:
            np.testing.assert_array_equal(cam.solids.grey[1], grey[1])
        assert first.shape == cam.frames.shape
