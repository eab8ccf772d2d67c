"""The car's archive: its frozen graph, converted by OpenVINO (the car's converter) and run by TensorFlow,
gives racerlab's policy outputs on 100 observations, for every sensor set and action space the car takes."""

from __future__ import annotations

import tarfile

import numpy as np
import pytest

from racerlab.errors import ConfigError
from racerlab.exchange import export_car, frozen_graph
from racerlab.exchange.graphdef import graph_bytes
from racerlab.exchange.local import open_for_export
from tests.exchange.conftest import make_model, observations, racerlab_policy_output

ov = pytest.importorskip("openvino", reason="the car check needs OpenVINO: pip install -e '.[test]'")

ONLINE = "main_level/agent/main/online"
PPO_OUT = f"{ONLINE}/network_1/ppo_head_0/policy"
SAC_OUT = "main_level/agent/policy/online/network_0/sac_policy_head_0/policy"
SENSOR = {"camera": "FRONT_FACING_CAMERA", "stereo": "STEREO_CAMERAS", "lidar": "LIDAR"}

CASES = [  # (racerlab init sensor, action space, algorithm, network)
    ("camera", "discrete", "clipped_ppo", None),
    ("camera", "continuous", "clipped_ppo", None),
    ("stereo", "discrete", "clipped_ppo", None),
    ("lidar", "continuous", "clipped_ppo", None),  # FRONT_FACING_CAMERA + LIDAR
    ("camera", "discrete", "clipped_ppo", "DEEP_CONVOLUTIONAL_NETWORK"),  # 5-layer CNN, dense per position
    ("camera", "continuous", "sac", None),
]


def _placeholders(model):
    scope = "main_level/agent/policy/online" if model.metadata.training_algorithm == "sac" else ONLINE
    names = {"camera": "FRONT_FACING_CAMERA", "stereo": "STEREO_CAMERAS", "lidar": "LIDAR"}
    return {k: f"{scope}/network_0/{names[k]}/{names[k]}" for k in model.shapes}


def _openvino_outputs(pb_path, model, obs, output):
    inputs = _placeholders(model)
    n = next(iter(obs.values())).shape[0]
    converted = ov.convert_model(str(pb_path), input=[(f"{inputs[k]}:0", [n, *s]) for k, s in model.shapes.items()],
                                 output=f"{output}:0")
    compiled = ov.Core().compile_model(converted, "CPU", {"INFERENCE_PRECISION_HINT": "f32"})
    feed = {f"{inputs[k]}:0": obs[k].astype(np.float32) for k in model.shapes}  # the car feeds raw 0-255 floats
    return compiled(feed)[compiled.output(0)]


@pytest.mark.parametrize("sensor,space,algorithm,network", CASES)
def test_openvino_converts_the_car_graph_to_racerlabs_policy(tmp_path, sensor, space, algorithm, network):
    folder = make_model(tmp_path / "m", sensor, space, algorithm, network)
    archive = export_car(folder.path, tmp_path / "m-car.tar.gz")
    with tarfile.open(archive) as tar:
        assert sorted(tar.getnames()) == ["agent/model.pb", "model_metadata.json"]
        tar.extractall(tmp_path / "car", filter="data")
    assert (tmp_path / "car" / "model_metadata.json").read_bytes() == folder.metadata_path.read_bytes()
    model = open_for_export(folder.path)[1]
    obs = observations(model.shapes)
    want = racerlab_policy_output(model, obs)
    output = SAC_OUT if algorithm == "sac" else PPO_OUT
    got = _openvino_outputs(tmp_path / "car" / "agent" / "model.pb", model, obs, output)
    assert got.shape == want.shape == (100, 10 if space == "discrete" else 2)
    diff = float(np.abs(got - want).max())
    print(f"openvino {sensor} {space} {algorithm} {network or 'SHALLOW'}: max abs diff {diff:.3g}")
    assert diff <= 1e-4
    if space == "discrete":
        np.testing.assert_allclose(got.sum(axis=1), 1.0, atol=1e-5)  # the node is the softmax, not logits
        assert (got.argmax(1) == want.argmax(1)).mean() >= 0.99


def test_tensorflow_runs_the_car_graph_like_racerlab(tmp_path):
    tf = pytest.importorskip("tensorflow", reason="needs TensorFlow: pip install -e '.[test]'")
    folder = make_model(tmp_path / "m", "lidar", "discrete")
    model = open_for_export(folder.path)[1]
    obs = observations(model.shapes)
    graph = tf.Graph()
    with graph.as_default():
        gd = tf.compat.v1.GraphDef()
        gd.ParseFromString(graph_bytes(frozen_graph(model)))
        tf.compat.v1.import_graph_def(gd, name="")
        feed = {graph.get_tensor_by_name(f"{name}:0"): obs[k].astype(np.float32)
                for k, name in _placeholders(model).items()}
        with tf.compat.v1.Session(graph=graph) as sess:
            got = sess.run(graph.get_tensor_by_name(f"{PPO_OUT}:0"), feed)
    diff = float(np.abs(got - racerlab_policy_output(model, obs)).max())
    print(f"tensorflow camera+lidar discrete: max abs diff {diff:.3g}")
    assert diff <= 1e-4


def test_a_features_model_is_refused_with_the_sensors_to_train(tmp_path):
    from racerlab.model import init_model

    folder = init_model(tmp_path / "f", sensor="features")
    with pytest.raises(ConfigError, match=r"car has no such sensor.*--sensor camera"):
        export_car(folder.path, tmp_path / "f-car.tar.gz")
    assert not (tmp_path / "f-car.tar.gz").exists()
