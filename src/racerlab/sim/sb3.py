"""Stable-Baselines3 adapter: SB3's `VecEnv` around the batched `racerlab/DeepRacer-v0` vector env.

`DeepRacerSB3VecEnv(num_envs, **env_kwargs)` is `gym.make_vec("racerlab/DeepRacer-v0", num_envs,
vectorization_mode="vector_entry_point", **env_kwargs)` seen through SB3's `VecEnv` contract: all
cars step in one batched simulator call (SB3's `DummyVecEnv` would step `num_envs` separate envs
one by one). Episodes reset themselves in the step that ends them, as SB3 expects; the ended
episode's last observation is `infos[i]["terminal_observation"]` and a step cap sets
`infos[i]["TimeLimit.truncated"]`. Each info also carries `episode_status`, `progress` and `steps`.

Needs the `sb3` extra (`pip install "racerlab[sb3]"`); nothing else in racerlab imports this module.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from racerlab.errors import ConfigError

try:
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv
except ImportError as exc:  # pragma: no cover - the sb3 extra is part of the test extra
    raise ConfigError('racerlab.sim.sb3: stable-baselines3 is not installed; fix: pip install "racerlab[sb3]"') \
        from exc

ENV_ID = "racerlab/DeepRacer-v0"


class DeepRacerSB3VecEnv(VecEnv):
    """`num_envs` DeepRacer cars in one batched simulator, as an SB3 `VecEnv` (see the module docstring)."""

    def __init__(self, num_envs: int = 1, **env_kwargs):
        # racerlab/DeepRacer-v0 is registered by the package root, imported with this module
        self.venv = gym.make_vec(ENV_ID, num_envs=num_envs, vectorization_mode="vector_entry_point", **env_kwargs)
        self._actions = None
        self._info_keys = ("episode_status", "progress", "steps")
        super().__init__(num_envs, self.venv.single_observation_space, self.venv.single_action_space)

    def reset(self):
        seed = next((s for s in self._seeds if s is not None), None)
        options = next((o for o in self._options if o), None)
        obs, info = self.venv.reset(seed=seed, options=options)
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = self._per_env(info)
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        obs, rewards, term, trunc, info = self.venv.step(self._actions)
        infos = self._per_env(info)
        if "final_obs" in info:
            for i in np.flatnonzero(info["_final_obs"]).tolist():
                final = info["final_info"]
                infos[i].update({k: final[k][i] for k in self._info_keys})
                infos[i]["terminal_observation"] = info["final_obs"][i]
                infos[i]["TimeLimit.truncated"] = bool(trunc[i] and not term[i])
        return obs, rewards.astype(np.float32), term | trunc, infos

    def _per_env(self, info) -> list[dict]:
        cols = [info[k].tolist() for k in self._info_keys]
        infos = [dict(zip(self._info_keys, row, strict=True)) for row in zip(*cols, strict=True)]
        if "params" in info:
            for d, p in zip(infos, info["params"], strict=True):
                d["params"] = p
        return infos

    def close(self) -> None:
        self.venv.close()

    def get_images(self):
        frames = self.venv.render()
        return [None] * self.num_envs if frames is None else list(frames)

    def _indices(self, indices) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        return [indices] if isinstance(indices, int) else list(indices)

    def get_attr(self, attr_name: str, indices=None) -> list:
        """One batched env serves every index: the attribute of the vector env, once per index."""
        value = getattr(self.venv.unwrapped, attr_name)
        return [value for _ in self._indices(indices)]

    def set_attr(self, attr_name: str, value, indices=None) -> None:
        if len(self._indices(indices)) != self.num_envs:
            raise ConfigError(f"racerlab.sim.sb3: set_attr({attr_name!r}) on some cars only; the cars share one "
                              "batched env, so set it for all (indices=None)")
        setattr(self.venv.unwrapped, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list:
        result = getattr(self.venv.unwrapped, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._indices(indices)]
