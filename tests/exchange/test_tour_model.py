"""The tour's camera model, trained a little, goes to all four targets, and each file is read back by its own
runtime on 1 000 observations: the car archive's model.pb by OpenVINO, DRoA's checkpoint restored by TensorFlow
into rl_coach's graph, model.onnx by onnxruntime, model.tflite by the TFLite interpreter."""

from __future__ import annotations

import tarfile
from pathlib import Path

import numpy as np
import pytest

from racerlab.exchange.export import car_feed, car_inputs, policy_tower
from racerlab.exchange.frames import car_observations
from racerlab.exchange.local import open_for_export
from tests.exchange.conftest import racerlab_policy_output
from tests.exchange.test_formats import REAL_FRAMES, check_agreement

tf = pytest.importorskip("tensorflow", reason="DRoA's checkpoint needs TensorFlow: pip install -e '.[test]'")
pytest.importorskip("onnxruntime", reason="needs onnxruntime: pip install -e '.[test]'")
pytest.importorskip("ai_edge_litert", reason="needs ai-edge-litert: pip install -e '.[test]'")
pytest.importorskip("openvino", reason="needs OpenVINO: pip install -e '.[test]'")

from racerlab.exchange.runtimes import OnnxRunner, OpenVinoRunner, TfliteRunner  # noqa: E402
from tests.exchange.test_virtual import P, _coach_graph  # noqa: E402


def _unpack(archive: Path) -> Path:
    where = archive.parent / archive.name.split(".")[0]
    with tarfile.open(archive) as tar:
        tar.extractall(where, filter="data")
    return where


def _droa_policy(root: Path, obs: np.ndarray, n_out: int) -> np.ndarray:
    """The policy of DRoA's checkpoint, restored with tf.train.Saver into rl_coach's shallow camera graph."""
    ckpt = root / "model" / (root / "model" / ".coach_checkpoint").read_text().strip()
    graph = tf.Graph()
    with graph.as_default():
        x = tf.compat.v1.placeholder(tf.float32, [None, 120, 160, 1],
                                     name=f"{P}/network_0/FRONT_FACING_CAMERA/FRONT_FACING_CAMERA")
        policy = tf.nn.softmax(_coach_graph(x, "network_1", "ppo_head_0/policy_fc", n_out))
        _coach_graph(x, "network_0", "v_values_head_0/output", 1)
        saver = tf.compat.v1.train.Saver(tf.compat.v1.global_variables())
        with tf.compat.v1.Session(graph=graph) as sess:
            saver.restore(sess, str(ckpt))
            return sess.run(policy, {x: obs.astype(np.float32)})


@pytest.mark.slow
def test_the_tours_camera_model_goes_to_every_target(tmp_path, monkeypatch):
    from racerlab.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["init", "cam-model", "--sensor", "camera", "--max-speed", "2"]) == 0
    assert main(["train", "cam-model", "--iterations", "1"]) == 0
    for flag in ("--car", "--droa", "--onnx", "--tflite"):
        assert main(["export", "cam-model", flag]) == 0
    opened, model = open_for_export(tmp_path / "cam-model")
    assert model.metadata.action_space_type == "discrete" and opened.checkpoint.iteration >= 1
    obs, n_real = car_observations(model.shapes, 1000, REAL_FRAMES)
    want = racerlab_policy_output(model, obs)
    feed = car_feed(model, obs)
    n_out = want.shape[1]
    _, _, output, _ = policy_tower(model)
    car = _unpack(tmp_path / "cam-model-car.tar.gz") / "agent" / "model.pb"
    droa = _unpack(tmp_path / "cam-model-droa.tar.gz")
    onnx = _unpack(tmp_path / "cam-model-onnx.tar.gz") / "model.onnx"
    lite = _unpack(tmp_path / "cam-model-tflite.tar.gz") / "model.tflite"
    check_agreement("car: openvino", OpenVinoRunner(car, car_inputs(model), output, batch=0)(feed), want, True)
    check_agreement("droa: tensorflow restore", _droa_policy(droa, obs["camera"], n_out), want, True)
    check_agreement("onnx: onnxruntime", OnnxRunner(onnx)(feed), want, True)
    check_agreement("tflite: litert", TfliteRunner(lite)(feed), want, True)
    print(f"{n_real} of the 1000 observations are the AWS simulator's frames; "
          f"racerlab picks {len(np.unique(want.argmax(1)))} different actions on them")
