"""`racerlab report`: one self-contained HTML file with every figure embedded."""

from __future__ import annotations

import base64
import re

import pytest

from racerlab.analysis.report import write_report
from racerlab.cli import main
from tests.analysis.test_rescore import train_tiny_model
from tests.conftest import aws_track_path


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    return train_tiny_model(tmp_path_factory.mktemp("report") / "model")


def _images(text: str) -> list[bytes]:
    return [base64.b64decode(m) for m in re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', text)]


def test_report_is_one_file_with_embedded_images(model, tmp_path, capsys):
    out = tmp_path / "sub" / "r.html"
    assert main(["report", str(model.path), "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    assert sorted(p.name for p in out.parent.iterdir()) == ["r.html"]  # nothing written beside it
    text = out.read_text(encoding="utf-8")
    images = _images(text)
    assert len(images) >= 10 and all(i[:8] == b"\x89PNG\r\n\x1a\n" for i in images)
    # nothing is loaded from elsewhere: every src/href is embedded data or an anchor in the page
    refs = re.findall(r'(?:src|href)="([^"]*)"', text)
    assert all(r.startswith(("data:image/png;base64,", "#")) for r in refs)
    for section in ("Training progress", "Lap times", "On the track", "Episode paths", "Action space usage",
                    "Speed and steering per waypoint", "reInvent2019_track"):
        assert section in text


def test_default_output_is_in_the_model_folder(model):
    out = write_report(model.path)
    assert out == model.path / "report.html" and out.is_file()


def test_log_without_a_track_still_reports_and_says_why(tmp_path):
    from racerlab.logs.synthetic import write_training_folder

    write_training_folder(tmp_path / "drfc", iterations=2, episodes_per_worker=3)
    out = write_report(tmp_path / "drfc", tmp_path / "r.html")
    text = out.read_text(encoding="utf-8")
    assert "Track figures left out" in text and "--track" in text
    assert len(_images(text)) >= 3  # progress, lap times, actions, waypoints


def test_given_track_and_a_single_csv(model, tmp_path):
    csv = next((model.path / "training-simtrace").glob("*.csv"))
    out = write_report(csv, tmp_path / "one.html", track=str(aws_track_path("reInvent2019_track")))
    assert "given with --track" in out.read_text(encoding="utf-8")


def test_the_track_comes_from_the_model_folder_else_from_the_logged_length(tmp_path):
    import pandas as pd

    from racerlab import track as tracks
    from racerlab.analysis.report import log_track
    from racerlab.model import init_model

    oval = tracks.load("lab_oval")
    df = pd.DataFrame({"track_len": [round(oval.length, 2)] * 3})  # logged on lab_oval
    folder = init_model(tmp_path / "m", track="lab_technical")
    t, note = log_track(folder.path, df)
    assert t.name == "lab_technical" and note == "from the model folder's training.toml"
    assert log_track(folder.path, df, "lab_oval")[0].name == "lab_oval"  # --track wins
    folder.config_path.write_text('[track]\nnames = ["no_such_track_anywhere"]\n')
    t, note = log_track(folder.path, df)
    assert t is None and "the model folder's track cannot be loaded" in note and "no_such_track_anywhere" in note
    folder.config_path.write_text('[track]\nnames = ["lab_technical"]\n')
    (tmp_path / "logs").mkdir()
    for not_a_model in (folder.reward_path, tmp_path / "logs"):  # a file, a folder without training.toml
        t, note = log_track(not_a_model, df)
        assert t.name == "lab_oval" and "the only known track" in note


def test_report_has_every_evaluation_and_one_iteration_numbering(model, tmp_path):
    from racerlab.evaluate import evaluate

    first = evaluate(model.path, trials=2)
    second = evaluate(model.path, trials=1, video=True, max_resets=0)  # ends at the first incident: a short video
    out = tmp_path / "r.html"
    text = write_report(model.path, out).read_text(encoding="utf-8")
    section = text[text.index('id="evaluations"'):text.index('id="laps"')]
    for res in (first, second):
        trials = "1 trial" if res.rules.trials == 1 else f"{res.rules.trials} trials"
        head = f"{res.out_dir.name}: checkpoint {res.checkpoint} on {res.track}, {trials} ("
        assert head in section
    assert section.index(first.out_dir.name) < section.index(second.out_dir.name)  # oldest first
    # each lap with its time, and the best lap, as the evaluation's summary has them
    for lap in first.laps:
        assert f"<th>{lap.trial}</th>" in section and f"<td>{lap.time:.4g}</td>" in section
    best = "-" if first.result.best_lap is None else f"{first.result.best_lap:.3f} s"
    assert f"best lap {best}" in section
    link = re.search(r'<a href="([^"]+)">video', section).group(1)
    assert (out.parent / link).resolve() == (second.out_dir / "evaluation.mp4").resolve()
    # iterations count from 1, as the console and the checkpoint names do (0-iteration.csv is iteration 1)
    table = text[text.index("<h3>Per iteration</h3>"):]
    assert re.search(r"<tbody>\s*<tr>\s*<th>(\d+)</th>", table).group(1) == "1"
    its = sorted(int(p.name.split("-")[0]) for p in (model.path / "training-simtrace").glob("*-iteration.csv*"))
    assert re.findall(r"<th>(\d+)</th>", table[:table.index("</table>")])[-1] == str(its[-1] + 1)
