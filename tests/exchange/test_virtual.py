"""DRoA's archive / DRfC's folder: the TF checkpoint restores into a graph built here with rl_coach's names and
shapes (independently of racerlab's writer) and gives racerlab's outputs; import gives the same actions back."""

from __future__ import annotations

import json
import tarfile

import numpy as np
import pytest
import torch

from racerlab.errors import ConfigError
from racerlab.exchange import export_drfc, export_droa, import_model
from racerlab.exchange.local import open_for_export
from tests.exchange.conftest import make_model, observations, racerlab_policy_output

tf = pytest.importorskip("tensorflow", reason="TF checkpoints need TensorFlow: pip install -e '.[test]'")

P = "main_level/agent/main/online"
CAMERA = "FRONT_FACING_CAMERA"


def _coach_graph(x, net: str, head: str, n_out: int):
    """rl_coach's shallow camera network on the shared input `x`, from its documented names, shapes and ops."""
    v1 = tf.compat.v1
    h = x / 255.0
    for i, (k, cin, cout, s) in enumerate([(8, 1, 32, 4), (4, 32, 64, 2), (3, 64, 64, 1)]):
        scope = f"{P}/{net}/{CAMERA}/Conv2d_{2 * i}"
        w = v1.get_variable(f"{scope}/kernel", [k, k, cin, cout])
        b = v1.get_variable(f"{scope}/bias", [cout])
        h = tf.nn.relu(tf.nn.conv2d(h, w, [1, s, s, 1], "VALID") + b)
    h = tf.reshape(h, [-1, 11 * 16 * 64])
    w = v1.get_variable(f"{P}/{net}/middleware_fc_embedder/Dense_0/kernel", [11264, 512])
    b = v1.get_variable(f"{P}/{net}/middleware_fc_embedder/Dense_0/bias", [512])
    h = tf.nn.relu(tf.matmul(h, w) + b)
    w = v1.get_variable(f"{P}/{net}/{head}/kernel", [512, n_out])
    b = v1.get_variable(f"{P}/{net}/{head}/bias", [n_out])
    return tf.matmul(h, w) + b


@pytest.mark.parametrize("space", ["discrete", "continuous"])
def test_droa_checkpoint_restores_into_coachs_graph_and_round_trips(tmp_path, space):
    folder = make_model(tmp_path / "m", "camera", space)
    archive = export_droa(folder.path, tmp_path / "m-droa.tar.gz")
    with tarfile.open(archive) as tar:
        names = set(tar.getnames())
        tar.extractall(tmp_path / "droa", filter="data")
    ck = "model/3_Step-1200.ckpt"
    assert {f"{ck}.index", f"{ck}.data-00000-of-00001", f"{ck}.meta", "model/.coach_checkpoint",
            "model/deepracer_checkpoints.json", "model/model_metadata.json", "model/model_3.pb",
            "ip/hyperparameters.json", "model_metadata.json", "reward_function.py", "training_params.yaml"} <= names
    root = tmp_path / "droa"
    assert (root / "model/.coach_checkpoint").read_text().strip() == "3_Step-1200.ckpt"
    index = json.loads((root / "model/deepracer_checkpoints.json").read_text())
    assert index["best_checkpoint"]["name"] == index["last_checkpoint"]["name"] == "3_Step-1200.ckpt"
    assert 'RACE_TYPE: "TIME_TRIAL"' in (root / "training_params.yaml").read_text()

    # the variable list of a console-trained model: names, shapes, the Adam slots and the target copy
    shapes = tf.train.load_checkpoint(str(root / ck)).get_variable_to_shape_map()
    n_out = 10 if space == "discrete" else 2
    head = "ppo_head_0/policy_fc" if space == "discrete" else "ppo_head_0/policy_mean"
    assert shapes[f"{P}/network_0/{CAMERA}/Conv2d_0/kernel"] == [8, 8, 1, 32]
    assert shapes[f"{P}/network_1/middleware_fc_embedder/Dense_0/kernel"] == [11264, 512]
    assert shapes[f"{P}/network_0/v_values_head_0/output/kernel"] == [512, 1]
    assert shapes[f"{P}/network_1/{head}/kernel"] == [512, n_out]
    assert shapes[f"{P}/{P}/network_1/{CAMERA}/Conv2d_4/kernel/Adam_1"] == [3, 3, 64, 64]
    assert shapes["main_level/agent/main/target/network_1/middleware_fc_embedder/Dense_0/bias"] == [512]
    for scalar in ("global_step", "beta1_power", "beta2_power", "Variable",
                   "network_0/gradients_from_head_0-0_rescalers"):
        assert shapes[f"{P}/{scalar}"] == []
    if space == "continuous":
        assert shapes[f"{P}/network_1/ppo_head_0/policy_log_std"] == [1, 2]
    # 101 variables in the console model's list (rl_coach_checkpoint_variables.md); discrete has no policy_log_std,
    # so 4 fewer (online, its 2 Adam slots, target)
    assert len(shapes) == (101 if space == "continuous" else 97)

    model = open_for_export(folder.path)[1]
    obs = observations(model.shapes)
    graph = tf.Graph()
    with graph.as_default():
        x = tf.compat.v1.placeholder(tf.float32, [None, 120, 160, 1], name=f"{P}/network_0/{CAMERA}/{CAMERA}")
        policy = _coach_graph(x, "network_1", head, n_out)
        value = _coach_graph(x, "network_0", "v_values_head_0/output", 1)
        if space == "discrete":
            policy = tf.nn.softmax(policy)
        saver = tf.compat.v1.train.Saver(tf.compat.v1.global_variables())
        with tf.compat.v1.Session(graph=graph) as sess:
            saver.restore(sess, str(root / ck))
            got_policy, got_value = sess.run([policy, value], {x: obs["camera"].astype(np.float32)})
    diff = float(np.abs(got_policy - racerlab_policy_output(model, obs)).max())
    with torch.no_grad():
        want_value = model.networks["value"]({"camera": torch.as_tensor(obs["camera"])}).numpy()
    print(f"tensorflow restore {space}: policy max abs diff {diff:.3g}")
    assert diff <= 1e-4
    assert float(np.abs(got_value[:, 0] - want_value).max()) <= 1e-4

    # import the archive back: same actions on 100 observations, reward kept as text
    back = open_for_export(import_model(archive, tmp_path / "back"))[1]
    t = {"camera": torch.as_tensor(obs["camera"])}
    with torch.no_grad():
        a, b = model.networks["policy"](t), back.networks["policy"](t)
    if space == "discrete":
        assert torch.equal(a.argmax(1), b.argmax(1))
    assert float((a - b).abs().max()) <= 1e-5
    kept = tmp_path / "back" / "imported" / "reward_function.py.txt"
    assert kept.read_bytes() == folder.reward_path.read_bytes()


def test_drfc_layout_and_import_from_the_folder(tmp_path):
    folder = make_model(tmp_path / "m", "camera", "discrete")
    out = export_drfc(folder.path, tmp_path / "drfc")
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()) == [
        "ip/hyperparameters.json", "model/.coach_checkpoint", "model/3_Step-1200.ckpt.data-00000-of-00001",
        "model/3_Step-1200.ckpt.index", "model/3_Step-1200.ckpt.meta", "model/deepracer_checkpoints.json",
        "model/model_3.pb", "model/model_metadata.json", "model_metadata.json", "reward_function.py",
        "training_params.yaml"]
    with pytest.raises(Exception, match="not empty"):
        export_drfc(folder.path, tmp_path / "drfc")
    imported = import_model(out, tmp_path / "back")
    assert json.loads((imported / "lineage.json").read_text())["imported"]["value_network"] == "imported"


def test_a_checkpoint_with_another_action_count_is_refused_with_both_numbers(tmp_path):
    folder = make_model(tmp_path / "m", "camera", "discrete")
    out = export_drfc(folder.path, tmp_path / "drfc")
    meta = json.loads((out / "model_metadata.json").read_text())
    meta["action_space"] = meta["action_space"][:7]
    for p in (out / "model_metadata.json", out / "model" / "model_metadata.json"):
        p.write_text(json.dumps(meta))
    with pytest.raises(ConfigError, match=r"checkpoint has 10 actions but model_metadata.json lists 7"):
        import_model(out, tmp_path / "back")
    assert not (tmp_path / "back").exists()


def test_a_corrupt_checkpoint_is_one_line_naming_the_file(tmp_path):
    folder = make_model(tmp_path / "m", "camera", "discrete")
    out = export_drfc(folder.path, tmp_path / "drfc")
    (out / "model" / "3_Step-1200.ckpt.index").write_bytes(b"not a table")
    with pytest.raises(ConfigError, match=r"3_Step-1200\.ckpt\.index: cannot read the TensorFlow checkpoint") as e:
        import_model(out, tmp_path / "back")
    assert "\n" not in str(e.value)
