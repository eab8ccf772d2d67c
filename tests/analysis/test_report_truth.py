"""The report says what it counts (issue 27): the best eval lap apart from the fastest training episode, a colour
bar that reads a constant speed, marked gaps in the per-iteration table, and progress while it is made."""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest

from racerlab.analysis.report import _iteration_table, write_report
from racerlab.cli import main


def _drfc_folder_with_metrics(tmp_path, eval_laps):
    """A synthetic DRfC training folder and racerlab's metrics.jsonl beside it, one entry per iteration with that
    iteration's fastest evaluation lap (None: none completed)."""
    from racerlab.logs.synthetic import write_training_folder

    folder = tmp_path / "drfc"
    write_training_folder(folder, iterations=2, episodes_per_worker=3)
    rows = [{"iteration": i, "eval/best_lap": lap} for i, lap in enumerate(eval_laps, 1)]
    (folder / "metrics").mkdir(exist_ok=True)
    (folder / "metrics" / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return folder


def _summary(text: str) -> dict[str, str]:
    table = text[text.index('id="summary"'):text.index("</table>", text.index('id="summary"'))]
    return dict(re.findall(r"<tr><td><b>([^<]*)</b></td><td>([^<]*)</td></tr>", table))


def test_the_best_eval_lap_is_the_training_s_evaluation_lap_not_a_training_episode(tmp_path):
    folder = _drfc_folder_with_metrics(tmp_path, [None, 9.4, 8.333, 8.333, 9.2])
    items = _summary(write_report(folder, tmp_path / "r.html").read_text(encoding="utf-8"))
    assert items["best eval lap"] == "8.333 s (iteration 3)"  # the earliest of the fastest
    assert "fastest training-episode lap" in items and "best lap" not in items


def test_a_log_without_metrics_jsonl_says_where_the_best_eval_lap_lives(tmp_path):
    from racerlab.logs.synthetic import write_training_folder

    write_training_folder(tmp_path / "drfc", iterations=2, episodes_per_worker=3)
    items = _summary(write_report(tmp_path / "drfc", tmp_path / "r.html").read_text(encoding="utf-8"))
    assert items["best eval lap"].startswith("not in these logs")


def test_a_constant_commanded_speed_gets_a_readable_colour_bar():
    from matplotlib.figure import Figure

    from racerlab.analysis.plots import _color_scale

    norm, cmap = _color_scale(np.full(200, 1.0), discrete=False)
    assert norm(1.0) == pytest.approx(0.5)  # the middle colour, not the bottom one (0 m/s on the bar)
    fig = Figure()
    ax = fig.add_subplot()
    sc = ax.scatter([0, 1], [0, 1], c=[1.0, 1.0], cmap=cmap, norm=norm)
    bar = fig.colorbar(sc, ax=ax)
    fig.canvas.draw()
    fmt = bar.ax.yaxis.get_major_formatter()
    assert fmt.get_offset() == ""  # no "1e-9+1" above the bar
    ticks = [float(t.get_text().replace("−", "-")) for t in bar.ax.get_yticklabels() if t.get_text()]
    assert min(ticks) < 1.0 < max(ticks) and max(ticks) - min(ticks) <= 0.25


def test_the_per_iteration_table_marks_the_iterations_it_leaves_out():
    its = pd.DataFrame({"episodes": np.arange(1, 51), "reward_mean": np.linspace(0, 1, 50)}, index=range(1, 51))
    t = _iteration_table(its)
    labels = [str(i) for i in t.index]
    assert labels[:10] == [str(i) for i in range(1, 11)] and labels[-30:] == [str(i) for i in range(21, 51)]
    assert labels[10] == "11–20: not shown" and t.iloc[10].isna().all()
    assert list(_iteration_table(its.head(40)).index) == list(range(1, 41))  # short tables are whole


def test_racerlab_report_says_what_it_is_doing(tmp_path, capsys):
    folder = _drfc_folder_with_metrics(tmp_path, [9.0, 8.5])
    assert main(["report", str(folder)]) == 0
    captured = capsys.readouterr()
    assert captured.out.strip() == str(folder / "report.html")
    steps = [line for line in captured.err.splitlines() if line.startswith("report: ")]
    assert steps[0].startswith(f"report: reading the logs in {folder}") and len(steps) >= 4
    assert all(re.search(r"\(\d+ s\)$", line) for line in steps)
