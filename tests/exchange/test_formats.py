"""ONNX and TFLite exports, read back by their consumers' own runtimes (onnxruntime, the TFLite interpreter), and
the car graph by OpenVINO: on 1 000 observations (the AWS simulator's frames, then racerlab's renders) each picks
racerlab's action on at least 999 and gives its outputs within 1e-4."""

from __future__ import annotations

import hashlib
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest

from racerlab.errors import ConfigError, RacerlabError
from racerlab.exchange import export_car, export_onnx, export_tflite
from racerlab.exchange.export import car_feed, car_inputs, policy_tower
from racerlab.exchange.frames import car_observations
from racerlab.exchange.local import open_for_export
from tests.exchange.conftest import make_model, racerlab_policy_output

pytest.importorskip("onnxruntime", reason="needs onnxruntime: pip install -e '.[test]'")
pytest.importorskip("ai_edge_litert", reason="needs ai-edge-litert: pip install -e '.[test]'")
pytest.importorskip("tensorflow", reason="the TFLite converter needs TensorFlow: pip install -e '.[test]'")
ov = pytest.importorskip("openvino", reason="the car check needs OpenVINO: pip install -e '.[test]'")

from racerlab.exchange.runtimes import OnnxRunner, OpenVinoRunner, TfliteRunner  # noqa: E402

REAL_FRAMES = Path(__file__).resolve().parents[2].parent / "shared" / "reference" / "gazebo_frames"
N = 1000

CASES = [  # (racerlab init sensor, action space, algorithm, network)
    ("camera", "discrete", "clipped_ppo", None),
    ("camera", "continuous", "clipped_ppo", None),
    ("stereo", "discrete", "clipped_ppo", None),
    ("lidar", "continuous", "clipped_ppo", None),  # FRONT_FACING_CAMERA + LIDAR
    pytest.param("camera", "continuous", "sac", None, marks=pytest.mark.slow),  # the community car runs no SAC
]


def _unpack(archive, where) -> dict[str, Path]:
    with tarfile.open(archive) as tar:
        tar.extractall(where, filter="data")
        return {m: Path(where) / m for m in tar.getnames()}


def agreement(got: np.ndarray, want: np.ndarray, discrete: bool) -> tuple[int, float]:
    """(how many observations get racerlab's action, max abs difference of the outputs)."""
    diff = float(np.abs(got - want).max())
    same = int((got.argmax(1) == want.argmax(1)).sum()) if discrete else int((np.abs(got - want).max(1) <= 1e-4).sum())
    return same, diff


def check_agreement(name: str, got, want, discrete: bool) -> None:
    same, diff = agreement(got, want, discrete)
    print(f"{name}: {same}/{len(want)} actions agree, max abs diff {diff:.3g}")
    assert got.shape == want.shape
    assert same >= 999 * len(want) // 1000
    assert diff <= 1e-4


@pytest.mark.parametrize("sensor,space,algorithm,network", CASES)
def test_each_runtime_takes_racerlabs_action_on_1000_observations(tmp_path, sensor, space, algorithm, network):
    folder = make_model(tmp_path / "m", sensor, space, algorithm, network)
    model = open_for_export(folder.path)[1]
    obs, n_real = car_observations(model.shapes, N, REAL_FRAMES)
    if REAL_FRAMES.is_dir():
        assert n_real == (4 if sensor == "stereo" else 12)  # 4 frames and 4 stereo pairs; a camera takes each eye
    want = racerlab_policy_output(model, obs)
    discrete = space == "discrete"
    if discrete:  # the frames must tell actions apart, or agreement says nothing
        assert len(np.unique(want.argmax(1))) >= 2
    feed = car_feed(model, obs)
    onnx = _unpack(export_onnx(folder.path, tmp_path / "m-onnx.tar.gz"), tmp_path / "onnx")
    check_agreement("onnxruntime", OnnxRunner(onnx["model.onnx"])(feed), want, discrete)
    lite = _unpack(export_tflite(folder.path, tmp_path / "m-tflite.tar.gz"), tmp_path / "tflite")
    check_agreement("tflite", TfliteRunner(lite["model.tflite"])(feed), want, discrete)
    _, _, output, _ = policy_tower(model)
    openvino = OpenVinoRunner(lite["model.pb"], car_inputs(model), output, batch=0)
    check_agreement("openvino", openvino(feed), want, discrete)


def test_the_tflite_archive_is_the_community_cars_model_folder(tmp_path):
    """What the car's optimizer and inference node look for: model.pb (it must exist even when the .tflite is
    cached), model.tflite beside it, checksum.txt = md5 of model.pb, model_metadata.json; the interpreter's inputs
    named after the sensors (the node matches them by name) with batch 1, output 0 one value per action."""
    folder = make_model(tmp_path / "m", "lidar", "discrete")
    files = _unpack(export_tflite(folder.path, tmp_path / "m-tflite.tar.gz"), tmp_path / "t")
    assert sorted(files) == ["checksum.txt", "model.pb", "model.tflite", "model_metadata.json"]
    pb = files["model.pb"].read_bytes()
    assert files["checksum.txt"].read_text().strip() == hashlib.md5(pb).hexdigest()
    assert files["model_metadata.json"].read_bytes() == folder.metadata_path.read_bytes()
    car = _unpack(export_car(folder.path, tmp_path / "m-car.tar.gz"), tmp_path / "car")
    assert car["agent/model.pb"].read_bytes() == pb  # the same graph the car archive carries
    runner = TfliteRunner(files["model.tflite"])
    details = {d["name"]: list(d["shape"]) for d in runner.it.get_input_details()}
    assert details == {"main_level/agent/main/online/network_0/FRONT_FACING_CAMERA/FRONT_FACING_CAMERA":
                       [1, 120, 160, 1], "main_level/agent/main/online/network_0/LIDAR/LIDAR": [1, 64]}
    out = runner.it.get_output_details()[0]
    assert out["name"] == "main_level/agent/main/online/network_1/ppo_head_0/policy" and list(out["shape"]) == [1, 10]


def test_the_onnx_model_keeps_the_car_graphs_names_and_takes_any_batch(tmp_path):
    folder = make_model(tmp_path / "m", "stereo", "continuous")
    files = _unpack(export_onnx(folder.path, tmp_path / "m-onnx.tar.gz"), tmp_path / "o")
    assert sorted(files) == ["model.onnx", "model_metadata.json"]
    session = OnnxRunner(files["model.onnx"]).session
    (inp,), (out,) = session.get_inputs(), session.get_outputs()
    assert inp.name == "main_level/agent/main/online/network_0/STEREO_CAMERAS/STEREO_CAMERAS"
    assert inp.shape == ["N", 120, 160, 2] and inp.type == "tensor(float)"
    assert out.name == "main_level/agent/main/online/network_1/ppo_head_0/policy" and out.shape == ["N", 2]


def test_a_features_model_is_refused_by_both_exports(tmp_path):
    from racerlab.model import init_model

    folder = init_model(tmp_path / "f", sensor="features")
    for export in (export_onnx, export_tflite):
        with pytest.raises(ConfigError, match=r"car has no such sensor.*--sensor camera"):
            export(folder.path, tmp_path / "f.tar.gz")
    assert not (tmp_path / "f.tar.gz").exists()


@pytest.mark.parametrize("flag,module,extra", [("--onnx", "onnx", "onnx"), ("--tflite", "tensorflow", "tflite")])
def test_a_missing_extra_is_one_line_naming_it(tmp_path, monkeypatch, capsys, flag, module, extra):
    from racerlab.cli import main

    folder = make_model(tmp_path / "m", "camera", "discrete")
    for name in [m for m in sys.modules if m == module or m.startswith(module + ".")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, module, None)  # `import module` now raises ImportError
    with pytest.raises(RacerlabError, match=rf"pip install 'racerlab\[{extra}\]'"):
        (export_onnx if extra == "onnx" else export_tflite)(folder.path, tmp_path / "x.tar.gz")
    assert main(["export", str(folder.path), flag, "-o", str(tmp_path / "x.tar.gz")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"racerlab[{extra}]" in err[0]
    assert not (tmp_path / "x.tar.gz").exists()
