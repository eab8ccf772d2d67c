"""TensorFlow checkpoints (V2 bundle: `.index`, `.data-00000-of-00001`, `.meta`) with rl_coach's variables.

Written and read with TensorFlow itself (`racerlab[tf]`): the bundle format's index is a LevelDB table of
protos that TensorFlow's protos in tensorboard do not cover, and the checkpoint must restore in the
DRoA/DRfC simapp's TensorFlow exactly, so racerlab lets TensorFlow's own Saver write it.

The variable set is that of a console-trained clipped-PPO model (`rl_coach_checkpoint_variables.md`):
`online` and `target` copies of the value (`network_0`) and policy (`network_1`) networks, each with its
head's loss-weight `Variable` [1] and `gradients_from_head_0-0_rescalers`; `global_step`, the `is_training`
flags, Adam's `beta1_power`/`beta2_power` and an `Adam`/`Adam_1` slot pair per online trainable variable
under the doubled prefix. The slots start at zero and the beta powers at one step, as a fresh optimizer.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from racerlab.errors import ConfigError, RacerlabError
from racerlab.exchange.coach import POLICY_NETWORK, PREFIX, VALUE_NETWORK, Tower

TF_HINT = "pip install 'racerlab[tf]'"
ADAM_BETA1, ADAM_BETA2 = 0.9, 0.999
TARGET_PREFIX = "main_level/agent/main/target"


def _tf():
    try:
        import tensorflow as tf
    except ImportError:
        raise RacerlabError(f"TensorFlow checkpoints need TensorFlow; {TF_HINT}") from None
    return tf


def coach_variables(policy: Tower, value: Tower, global_step: int) -> dict[str, np.ndarray]:
    """Every variable of the clipped-PPO coach graph, name -> value (int64 / bool / float32 arrays)."""
    online: dict[str, np.ndarray] = {f"{PREFIX}/global_step": np.array(global_step, np.int64),
                                     f"{PREFIX}/Variable": np.array(False)}  # is_training
    target: dict[str, np.ndarray] = {f"{TARGET_PREFIX}/Variable": np.array(False)}
    trainable: list[str] = []
    for prefix, part in ((PREFIX, online), (TARGET_PREFIX, target)):
        for network, tower in ((VALUE_NETWORK, value), (POLICY_NETWORK, policy)):
            net = tower.variables(network, prefix)
            part.update(net)
            part[f"{prefix}/{network}/Variable"] = np.ones(1, np.float32)  # the head's loss weight
            rescaler = f"{prefix}/{network}/gradients_from_head_0-0_rescalers"
            part[rescaler] = np.array(1.0, np.float32)
            if prefix == PREFIX:
                trainable += [*net, rescaler]
    online[f"{PREFIX}/beta1_power"] = np.array(ADAM_BETA1, np.float32)
    online[f"{PREFIX}/beta2_power"] = np.array(ADAM_BETA2, np.float32)
    for name in trainable:
        for slot in ("Adam", "Adam_1"):
            online[f"{PREFIX}/{name}/{slot}"] = np.zeros_like(online[name])
    return {**online, **target}


def write_checkpoint(prefix: Path, variables: dict[str, np.ndarray]) -> list[Path]:
    """Save `variables` as a TF1 checkpoint at `prefix` (e.g. `model/3_Step-1200.ckpt`) with a `.meta` graph."""
    tf = _tf()
    v1 = tf.compat.v1
    graph = tf.Graph()
    with graph.as_default():
        tf_vars, feeds, assigns = [], {}, []
        for name, value in variables.items():
            dtype = tf.as_dtype(value.dtype)
            var = v1.get_variable(name, shape=value.shape, dtype=dtype, initializer=v1.zeros_initializer(),
                                  use_resource=False, trainable=False)
            ph = v1.placeholder(dtype, value.shape, name=f"racerlab_assign/{len(tf_vars)}")
            assigns.append(v1.assign(var, ph))
            feeds[ph] = value
            tf_vars.append(var)
        saver = v1.train.Saver(var_list=tf_vars, save_relative_paths=True, max_to_keep=None)
        with v1.Session(graph=graph) as sess:
            sess.run(assigns, feed_dict=feeds)
            saver.save(sess, str(prefix), write_meta_graph=True, write_state=False)
    return [Path(f"{prefix}{ext}") for ext in (".index", ".data-00000-of-00001", ".meta")]


class CheckpointReader:
    """Variables of a TF checkpoint by name (None when absent)."""

    def __init__(self, prefix: Path):
        tf = _tf()
        self.path = Path(prefix)
        try:
            self._reader = tf.train.load_checkpoint(str(prefix))
        except Exception as exc:  # noqa: BLE001 - TF raises several types for a damaged bundle
            first = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
            raise ConfigError(f"{prefix}.index: cannot read the TensorFlow checkpoint ({first}); copy the "
                              "model's .ckpt.index and .ckpt.data-* files again") from None
        self.shapes = self._reader.get_variable_to_shape_map()

    def lookup(self, name: str) -> np.ndarray | None:
        if name not in self.shapes:
            return None
        try:
            return self._reader.get_tensor(name)
        except Exception as exc:  # noqa: BLE001
            raise ConfigError(f"{self.path}.data-00000-of-00001: cannot read {name} ({type(exc).__name__}); "
                              "the checkpoint is damaged") from None
