"""Video pieces: the camera picture found in any observation layout, the track canvas, the camera inset."""

from __future__ import annotations

import numpy as np
import pytest

from racerlab.evaluate.rules import RaceRules
from racerlab.evaluate.runner import run_evaluation
from racerlab.evaluate.video import TrackCanvas, _Hud, _Side, camera_image, car_polygon, lap_ends, render_video
from tests.evaluate.test_runner import pursuit, world_on


def test_camera_image_from_any_layout():
    grey = np.arange(120 * 160, dtype=np.uint8).reshape(1, 120, 160)
    assert camera_image(grey).shape == (120, 160)
    assert camera_image(np.ones((1, 1, 120, 160), np.float32)).max() == 255  # [0, 1] floats, channels first
    stereo = camera_image(np.zeros((1, 2, 120, 160), np.uint8))
    assert stereo.shape == (120, 320)  # the two cameras side by side
    assert camera_image(np.zeros((1, 120, 160, 2), np.uint8)).shape == (120, 320)  # channels last
    both = {"lidar": np.zeros((1, 64), np.float32), "camera": grey}
    assert camera_image(both) is not None and camera_image(np.zeros((1, 20), np.float32)) is None


def test_canvas_keeps_metres_square_and_sizes_even(aws_track):
    track = aws_track("reInvent2019_wide")
    c = TrackCanvas(track, width_px=640)
    assert c.width % 16 == 0 and c.height % 16 == 0 and c.background.shape == (c.height, c.width, 3)
    px, py = c.px([c.x0, c.x1], [c.y1, c.y0])
    assert px == pytest.approx([0, c.width]) and py == pytest.approx([0, c.height])
    poly = np.array(car_polygon(c, 0.0, 0.0, 0.0))
    assert np.ptp(poly[:, 0]) == pytest.approx(0.324 * c.scale) and np.ptp(poly[:, 1]) == pytest.approx(0.196 * c.scale)


def test_video_with_a_camera_inset(tmp_path, aws_track):
    imageio = pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    track = aws_track("reInvent2019_wide")
    w = world_on(track)
    white = np.full((1, 120, 160), 255, np.uint8)
    run = run_evaluation(w, pursuit(w, 3.0), RaceRules(trials=1), keep_frames=True, image_of=lambda obs: white[0])
    seen = []
    path = render_video(tmp_path / "v.mp4", track, run, width_px=640, progress=lambda done, total: seen.append(done))
    frames = imageio.mimread(path, memtest=False)
    assert len(frames) == run.rows and seen[-1] == run.rows
    top_right = np.asarray(frames[5])[20:200, -300:-30]
    assert (top_right > 240).all(axis=-1).mean() > 0.8  # the white camera picture, twice its size
    assert not list(tmp_path.glob(".*partial*"))
    # the text and pictures sit in a panel right of the track: the track's corners are as drawn
    canvas = TrackCanvas(track, 640)
    frame = np.asarray(frames[-1]).astype(int)
    assert frame.shape[1] > canvas.width
    corner = np.abs(frame[:28, :80] - canvas.background[:28, :80].astype(int)).max(axis=-1)
    assert (corner > 80).mean() < 0.002  # the margin beyond the track: H.264 noise only, no dark text


def test_lap_list_fits_the_panel_whatever_the_laps():
    canvas = type("C", (), {"width": 640, "height": 400})()
    heights = []
    for laps in (1, 3, 40):
        hud = _Hud("model", laps, 4.0, 1)
        side = _Side(canvas, hud, None, 1)
        # title, clock, speed, state and every lap's line, then the colour scale, all inside the frame
        assert side.height >= hud.text_height() + 50 and side.height % 16 == 0 and side.x0 == 640
        heights.append(side.height)
    assert heights[0] == heights[1] == 400 and heights[2] > 400  # 40 laps need a taller frame


def test_laps_end_at_progress_100_whatever_the_status():
    trace = {"episode_status": np.array(["prepare", "in_progress", "in_progress", "in_progress", "pause",
                                         "lap_complete"]),
             "progress": np.array([0.0, 50.0, 100.0, 3.0, 100.0, 100.0])}
    assert lap_ends(trace).tolist() == [False, False, True, False, False, True]


def test_video_draws_the_race_s_boxes(tmp_path, aws_track):
    imageio = pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    from racerlab.evaluate.video import BOX_FILL
    from racerlab.sim import World
    from racerlab.spec import RaceConfig
    from tests.evaluate.test_runner import META

    track = aws_track("reInvent2019_wide")
    race = RaceConfig(type="object_avoidance", object_positions=[[0.5, 1]])
    w = World(track, 1, META, None, "features", max_episode_steps=300, seed=0, race=race)
    run = run_evaluation(w, pursuit(w, 1.0), RaceRules(trials=1), keep_frames=True)
    assert run.objects is not None and len(run.objects["pose"]) == run.rows and not run.objects["cars"]
    (bx, by, _), = run.objects["pose"][0]
    path = render_video(tmp_path / "v.mp4", track, run, width_px=640)
    frame = np.asarray(imageio.mimread(path, memtest=False)[0]).astype(int)
    c = TrackCanvas(track, width_px=640)
    col, row = (int(round(float(v))) for v in c.px(bx, by))
    assert np.abs(frame[row, col] - np.array(BOX_FILL[:3])).max() < 25  # the box's cardboard, at its place


def test_every_second_step_is_still_real_time(tmp_path, aws_track):
    imageio = pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    track = aws_track("reInvent2019_wide")
    w = world_on(track)
    run = run_evaluation(w, pursuit(w, 3.0), RaceRules(trials=1))
    path = render_video(tmp_path / "v.mp4", track, run, width_px=640, frame_every=2)
    reader = imageio.get_reader(path)
    assert reader.get_meta_data()["fps"] == 7.5
    assert reader.count_frames() == (run.rows + 1) // 2  # the rows n-1, n-3, ...: the last step always shown
