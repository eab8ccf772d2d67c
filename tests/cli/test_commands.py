"""The `racerlab` command in-process: init, train, clone, quickstart, and one-line errors."""

from __future__ import annotations

import json

import pytest

from racerlab.cli import main
from tests.conftest import aws_track_path


def test_help_lists_every_command(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    for cmd in ("quickstart", "init", "train", "clone", "tracks", "evaluate"):
        assert cmd in out


def test_init_train_clone(tmp_path, capsys):
    track = str(aws_track_path("reInvent2019_track"))
    model = tmp_path / "m"
    assert main(["init", str(model), "--track", track, "--max-speed", "2"]) == 0
    assert main(["train", str(model), "--iterations", "2", "--cars", "8"]) == 0
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line[:5].strip().isdigit()]
    assert [r[0] for r in rows] == ["1", "2"] and "stopped: iteration limit of 2" in out
    training = out[out.index("training "):out.index("model: ")]  # the trainer's own lines
    assert max(len(line) for line in training.splitlines()) <= 80
    assert main(["clone", str(model), str(tmp_path / "c"), "--checkpoint", "last"]) == 0
    assert json.loads((tmp_path / "c" / "lineage.json").read_text())["checkpoint"].startswith("2_Step-")


def test_user_mistakes_are_one_line(tmp_path, capsys):
    assert main(["train", str(tmp_path / "nothing")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("racerlab: error:") and "no such model folder" in err and "\n" not in err
    model = tmp_path / "m"
    main(["init", str(model), "--track", str(aws_track_path("reInvent2019_track"))])
    (model / "hyperparameters.json").write_text(json.dumps({"lr": "fast"}))
    assert main(["train", str(model), "--iterations", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "hyperparameters.json" in err and "lr" in err and "\n" not in err
    assert main(["init", str(tmp_path / "x"), "--track", "no_such_track"]) == 2
    assert "unknown track 'no_such_track'" in capsys.readouterr().err


def test_quickstart_on_defaults(tmp_path, capsys):
    model = tmp_path / "qs"
    # a fixed number of iterations, not minutes: a cold numba cache on a loaded machine can use up a short time
    # limit before the first iteration ends, leaving no metrics to show
    assert main(["quickstart", "--model", str(model), "--iterations", "2"]) == 0
    out = capsys.readouterr().out
    assert "result:" in out and (model / "quickstart" / "evaluation.png").is_file()
    assert "stopped: iteration limit of 2" in " ".join(out.split())
    # which checkpoint drove the laps, what training changed, then what to run next, each command naming the model
    summary = json.loads(next(model.glob("evaluation-*/summary.json")).read_text())
    own = out[out.index("laps 1-3 above"):out.index("next:\n")]  # the quickstart's own lines fit 80 columns
    assert all(len(line) <= 80 or len(line.split()) == 1 for line in own.splitlines())  # only a long path is longer
    text = " ".join(own.split())
    assert f"laps 1-3 above: driven by checkpoint {summary['checkpoint']} (iteration " in text
    assert "the fastest evaluation laps during training, the newest of those within a step)" in text
    assert "training: iteration 2" in text or "what training changed, iteration 1 -> iteration 2" in text
    block = out[out.index("next:\n"):].splitlines()[1:]
    commands = [line.strip() for line in block if line.strip() and not line.strip().startswith("#")]
    commands = [c.split("  #")[0].strip() for c in commands]
    assert commands[0] == f"racerlab report {model}" and commands[1] == f"racerlab evaluate {model} --video"
    assert any(c.startswith("racerlab reward check my_reward.py") for c in commands)
    assert any(c.startswith(f"racerlab clone {model} my-model --reward my_reward.py") for c in commands)
    assert all(map(_fits_or_is_a_whole_command, block)), block
    assert "sensor FEATURES" in out and "racerlab's own" in out
    assert (model / "quickstart" / "training.png").is_file()
    assert list(model.glob("evaluation-*/EvalMetrics.json"))
    # its model: continuous actions up to 4 m/s and the racing_line reward on the limit's path 0.1 m over the borders
    meta = json.loads((model / "model_metadata.json").read_text())
    assert meta["action_space_type"] == "continuous" and meta["action_space"]["speed"]["high"] == 4.0
    assert "RACING_LINE = [  # " in (model / "reward_function.py").read_text()
    assert "margin -0.1 m" in (model / "reward_function.py").read_text()
    # the quickstart keeps the newest checkpoint whose mean evaluation lap is within one step (1/15 s) in one of
    # its 5 laps of the fastest mean lap so far
    assert 'best_model_metric = "laptime"' in (model / "training.toml").read_text()
    rows = [json.loads(line) for line in (model / "metrics" / "metrics.jsonl").read_text().splitlines()]
    assert [r["iteration"] for r in rows] == [1, 2] and all(r["eval/metric"] is not None for r in rows)
    first, second = rows[0]["eval/metric"], rows[1]["eval/metric"]
    kept = rows[1] if second <= first + 1000 / 15 / 5 + 1e-6 else rows[0]
    best = json.loads((model / "checkpoints" / "deepracer_checkpoints.json").read_text())["best_checkpoint"]
    assert best["name"].startswith(f"{kept['iteration']}_Step-") and best["avg_eval_metric"] == kept["eval/metric"]


def _fits_or_is_a_whole_command(line: str) -> bool:
    """80 columns, unless the line is a command (never wrapped, to be copied) or a comment's one long path."""
    words = line.split()
    return len(line) <= 80 or (words[0] == "#" and len(words) == 2) or (words[0] != "#" and "#" not in words)


def test_the_next_steps_fit_80_columns_and_keep_each_command_whole(tmp_path):
    from racerlab.cli.quickstart import next_steps

    for model in (tmp_path.parent / "m", tmp_path / ("a-long-folder-name" * 3) / "quickstart-model"):
        block = next_steps(model).splitlines()[1:]
        assert all(map(_fits_or_is_a_whole_command, block)), block
        commands = [line.strip().split("  #")[0] for line in block if not line.strip().startswith("#")]
        assert commands[0] == f"racerlab report {model}" and commands[1] == f"racerlab evaluate {model} --video"
        assert commands[-1] == "racerlab train my-model --minutes 5" and len(commands) == 7


def test_init_says_a_features_model_is_racerlab_only(tmp_path, capsys):
    assert main(["init", str(tmp_path / "f")]) == 0
    out = capsys.readouterr().out
    assert "FEATURES" in out and "AWS console and DRfC accept only cameras and LIDAR" in out
    assert json.loads((tmp_path / "f" / "model_metadata.json").read_text())["sensor"] == ["FEATURES"]
    assert main(["init", str(tmp_path / "c"), "--sensor", "camera"]) == 0
    assert "racerlab's own" not in capsys.readouterr().out
    assert json.loads((tmp_path / "c" / "model_metadata.json").read_text())["sensor"] == ["FRONT_FACING_CAMERA"]


def test_init_best_model_metric_flag(tmp_path, capsys):
    model = tmp_path / "m"
    assert main(["init", str(model), "--best-model-metric", "reward"]) == 0
    assert 'best_model_metric = "reward"' in (model / "training.toml").read_text()
    assert main(["init", str(tmp_path / "d")]) == 0
    assert 'best_model_metric = "progress"' in (tmp_path / "d" / "training.toml").read_text()  # AWS default
    with pytest.raises(SystemExit):
        main(["init", str(tmp_path / "x"), "--best-model-metric", "fastest"])
    assert "invalid choice: 'fastest'" in capsys.readouterr().err


def test_printed_commands_quote_their_paths(tmp_path, capsys):
    import re
    import shlex

    model = tmp_path / "my model's folder"  # a space and a quote: pasted unquoted, the command breaks
    assert main(["init", str(model), "--track", str(aws_track_path("reInvent2019_track"))]) == 0
    assert main(["train", str(model), "--iterations", "1", "--cars", "2", "--episodes", "2"]) == 0
    assert main(["clone", str(model), str(tmp_path / "a clone")]) == 0
    found = re.findall(r"`(racerlab [^`]*)`", capsys.readouterr().out)
    commands = [c for c in found if str(tmp_path) in c]  # not advice without a path (`racerlab init --sensor camera`)
    assert len(commands) >= 4
    for cmd in commands:
        args = shlex.split(cmd)
        assert str(model) in args or str(tmp_path / "a clone") in args, cmd


def test_sigint_stops_a_training_started_with_sigint_ignored(tmp_path):
    """A job a shell puts in the background inherits SIGINT ignored; `kill -INT` (the console's stop) must still
    save the last complete iteration and end it."""
    import os
    import signal
    import subprocess
    import sys

    model = tmp_path / "m"
    assert main(["init", str(model), "--track", str(aws_track_path("reInvent2019_track")), "--cars", "2"]) == 0
    hp = json.loads((model / "hyperparameters.json").read_text())
    (model / "hyperparameters.json").write_text(json.dumps({**hp, "num_episodes_between_training": 2}))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    child = subprocess.Popen([sys.executable, "-m", "racerlab", "train", str(model), "--iterations", "100000"],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        lines = []
        for line in child.stdout:  # wait for the first iteration's line
            lines.append(line)
            if line[:5].strip().isdigit():  # the first iteration's row of the table
                break
        child.send_signal(signal.SIGINT)
        out, _ = child.communicate(timeout=120)
    finally:
        if child.poll() is None:
            child.kill()
    # 130 as for a Ctrl-C during set-up, so `racerlab train m && racerlab evaluate m` stops here
    assert child.returncode == 130 and "interrupted (Ctrl-C)" in "".join(lines) + out
    assert any(p.name.endswith(".pt") for p in (model / "checkpoints").iterdir())
