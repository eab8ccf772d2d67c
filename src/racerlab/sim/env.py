"""Gymnasium adapters: `racerlab/DeepRacer-v0` for one car and its batched vector version.

## Action Space
From `model_metadata`: `Discrete(n)` for a discrete AWS action list, or `Box(-1, 1, (2,))` for a
continuous one (`[steering, speed]`, clipped and rescaled linearly to the configured ranges as
AWS does). The simulator then clips steering to ±30° and speed to [0.1, 4] m/s.

## Observation Space
Chosen by `observation` ("features", or a sensor such as "camera" once registered), else by the
model's `sensor` list; with neither, `features`. `look` ("aws", the default, or "classic") is how the world
looks to a camera, in the observation and in `render()`.

## Rewards
`reward_function(params)` (a callable or a path to an AWS `reward_function.py`) gets the AWS
params dict (`info["params"]`); the first step of every episode is AWS's prepare step: the
action is ignored, the reward is 0 and the function is not called. Without a reward function
the reward is 0 and no params are built (the fastest path).

## Episode Termination
`terminated` on lap_complete, off_track, immobilized or reversed (`info["episode_status"]`, the
AWS names); `truncated` at `max_episode_steps`. Rewards and termination are judged on the pose
the observation was taken in, as AWS does, unless `reward_order="after_action"`.

`reset(seed=...)` reseeds and restarts the round-robin start sequence, so seeded runs repeat.
The env's `car` is the car it drives (`car=`: a simulator name, a `[car]` table or a `CarParams`; default the
droa car for the model's version), and `reset`'s info names it (`info["car"]`, e.g. "droa, velocity control
(version >= 5)").

## Races
`race=` takes the `[race]` table (or a `RaceConfig`, or a type name): boxes and bot cars are the car's
objects. In a `head_to_model` race the env holds a second car, the opponent, driven by `opponent(obs) ->
action` (car 1's observation, the same spaces; e.g. another model's policy) or, by default, by a pure-pursuit
driver on the centre line at `opponent_speed` m/s. The opponent starts `opponent_gap` of the lap ahead of the
car and, when its own episode ends, restarts that far ahead of the car again; each car sees the other (lidar,
camera, `objects_*`) and crashes into it by the crash rule. Reward, termination and info are the car's alone.

## Rendering
`render_mode="rgb_array"` (what SB3's `make_vec_env` asks for): `render()` returns the car's front
camera as an (H, W, 3) uint8 image (the grey camera repeated into three channels); the vector env
returns a tuple of them, one per car. The camera is built on the first `render()` call.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from racerlab.errors import ConfigError
from racerlab.sim import _kernels as K
from racerlab.sim.objects import as_race
from racerlab.sim.pursuit import PurePursuit
from racerlab.sim.world import World
from racerlab.spec import MODEL_POINT_AHEAD_M, STATUS_NAMES, STEPS_PER_SECOND
from racerlab.track import DEFAULT_TRACK

_STATUS_OBJ = np.array(STATUS_NAMES, dtype=object)
RENDER_MODES = ["rgb_array"]


def _check_render_mode(render_mode):
    if render_mode is not None and render_mode not in RENDER_MODES:
        raise ConfigError(f"racerlab/DeepRacer-v0: render_mode {render_mode!r} is not supported; "
                          f"use one of {RENDER_MODES} or None")
    return render_mode


def _camera_frames(env, rows):
    """(len(rows), H, W, 3) uint8 front-camera images, the camera built on first use."""
    if env._camera is None:
        from racerlab.sim.sensors.camera import Camera  # the raster is built only when someone renders
        from racerlab.sim.sensors.look import LOOKS

        env._camera = Camera(env.world.sim, look=LOOKS[env.look])
    grey = env._camera.render(rows)[rows, :, :, 0]
    return np.repeat(grey[..., None], 3, axis=-1)


class DeepRacerEnv(gym.Env):
    """One DeepRacer car (see the module docstring)."""

    metadata = {"render_modes": RENDER_MODES, "render_fps": STEPS_PER_SECOND}

    def __init__(self, track=DEFAULT_TRACK, reward_function=None, model_metadata=None, observation=None, *,
                 car=None, start=None, max_episode_steps=10_000, reward_order="aws", seed=None, render_mode=None,
                 race=None, opponent=None, opponent_speed: float = 1.0, opponent_gap: float = 0.1, look="aws"):
        race = as_race(race)
        pair = race is not None and race.head_to_model
        self.world = World(track, 2 if pair else 1, model_metadata, reward_function, observation, car=car,
                           start=start, max_episode_steps=max_episode_steps, reward_order=reward_order, seed=seed,
                           keep_params=True, race=race, look=look)
        self.look = look
        self.sim = self.world.sim
        self.car = self.sim.car_params  # the car it drives; `reset`'s info names it ("car")
        self._opponent = _Opponent(self.world, opponent, opponent_speed, opponent_gap) if pair else None
        self.action_space = self.world.action_space
        self.observation_space = self.world.observation.space
        self.render_mode = _check_render_mode(render_mode)
        self._camera = None

    def render(self):
        if self.render_mode is None:
            return None
        return _camera_frames(self, np.zeros(1, dtype=np.int64))[0]

    def _obs(self):
        o = self.world.observation()
        return {k: v[0] for k, v in o.items()} if isinstance(o, dict) else o[0]

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        if seed is not None:
            self.sim.reseed(seed)
        options = options or {}
        mask = None if self._opponent is None else np.array([True, False])
        self.sim.reset(mask, start_ndist=options.get("start_ndist"), reverse=options.get("reverse"))
        if self._opponent is not None:
            self._opponent.restart()
        return self._obs(), {**self._info(None), "car": self.car.name}

    def step(self, action):
        if self._opponent is None:
            codes, rewards = self.world.step(np.asarray(action)[None])
        else:
            codes, rewards = self._opponent.step(action)
        term, trunc = self.world.done(codes)
        if self._opponent is not None and (term[1] or trunc[1]):
            self._opponent.restart()
        return self._obs(), float(rewards[0]), bool(term[0]), bool(trunc[0]), self._info(self.world.params, codes)

    def _info(self, params, codes=None):
        sim = self.sim
        code = int(sim.status[0] if codes is None else codes[0])
        prog = sim.state.progress[0] if codes is None else sim.judged.progress[0]
        info = {"episode_status": STATUS_NAMES[code], "progress": float(prog),
                "steps": int(sim.steps[0])}
        if params is not None and params[0] is not None:
            info["params"] = params[0]
        return info


class _Opponent:
    """The second car of a one-car env's head-to-model race: driven by `policy(obs) -> action` or, without one,
    by pure pursuit of the centre line at `speed`; restarted `gap` of the lap ahead of car 0."""

    def __init__(self, world: World, policy, speed: float, gap: float):
        if policy is not None and not callable(policy):
            raise ConfigError(f"racerlab/DeepRacer-v0: opponent must be a callable obs -> action, got {policy!r}")
        if not 0.0 < gap < 1.0:
            raise ConfigError(f"racerlab/DeepRacer-v0: opponent_gap {gap!r} must be a fraction of the lap in (0, 1)")
        self.world = world
        self.policy = policy
        sim = world.sim
        self.pursuits = None if policy is not None else \
            [PurePursuit.on_centre_line(t, speed) for t in (sim.track, sim.track_reversed)]
        self.gap = gap

    def restart(self) -> None:
        """Car 1 starts a new episode `gap` of the lap ahead of car 0, in its direction."""
        sim = self.world.sim
        state = sim.state
        rev = bool(state.reversed[0])
        length = (sim.track_reversed if rev else sim.track).length
        base = float(state.projection_distance[0]) - MODEL_POINT_AHEAD_M  # car 0's base, along the centre line
        ahead = (base / length + self.gap) % 1.0
        sim.reset(np.array([False, True]), start_ndist=ahead, reverse=rev)

    def step(self, action) -> tuple[np.ndarray, np.ndarray]:
        """Both cars one step: car 0 with `action`, car 1 with its driver's; the rewards are car 0's."""
        world, sim = self.world, self.world.sim
        steer0, speed0 = world.commands(np.asarray(action)[None])
        if self.policy is not None:
            o = world.observation()
            mine = {k: v[1] for k, v in o.items()} if isinstance(o, dict) else o[1]
            steer1, speed1 = world.commands(np.asarray(self.policy(mine))[None])
        else:
            steer, speed = self.pursuits[int(sim.ctr[1, K.KREV])](sim)
            steer1, speed1 = steer[1:], speed[1:]
        codes = sim.step(np.concatenate([steer0, steer1]), np.concatenate([speed0, speed1])).copy()
        return codes, world.rewards(codes, np.array([True, False]))


class DeepRacerVectorEnv(gym.vector.VectorEnv):
    """`num_envs` cars in one batched simulator, with same-step autoreset.

    A finished car is reset in the step that ends its episode: the returned observation is its
    next episode's first, and `info["final_obs"]` / `info["final_info"]` (masked by
    `info["_final_obs"]`) hold the last observation and info of the episode that ended.
    With `info_params=True`, `info["params"]` is a list with each car's params dict (None on prepare
    steps); it is off by default because keeping a dict per car per step costs more than the step.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": RENDER_MODES,
                "render_fps": STEPS_PER_SECOND}

    def __init__(self, num_envs: int = 1, track=DEFAULT_TRACK, reward_function=None, model_metadata=None,
                 observation=None, *, car=None, start=None, max_episode_steps=10_000, reward_order="aws", seed=None,
                 info_params=False, render_mode=None, race=None, look="aws"):
        self.world = World(track, num_envs, model_metadata, reward_function, observation, car=car, start=start,
                           max_episode_steps=max_episode_steps, reward_order=reward_order, seed=seed,
                           keep_params=info_params, race=race, look=look)
        self.look = look
        self.sim = self.world.sim
        self.car = self.sim.car_params  # the car every env drives; `reset`'s info names it ("car", one per env)
        self.num_envs = num_envs
        self.single_action_space = self.world.action_space
        self.single_observation_space = self.world.observation.space
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.render_mode = _check_render_mode(render_mode)
        self._camera = None

    def render(self):
        if self.render_mode is None:
            return None
        return tuple(_camera_frames(self, np.arange(self.num_envs, dtype=np.int64)))

    def reset(self, *, seed=None, options=None):
        if seed is not None:
            self.sim.reseed(seed)
            self.action_space.seed(seed)
        options = options or {}
        self.sim.reset(options.get("reset_mask"), start_ndist=options.get("start_ndist"),
                       reverse=options.get("reverse"))
        info = self._info(self.sim.status.copy(), None, self.sim.state.progress)
        info["car"], info["_car"] = self._car_info(np.ones(self.num_envs, dtype=bool))
        return self.world.observation(), info

    def _car_info(self, rows):
        return np.where(rows, self.car.name, None).astype(object), rows.copy()

    def step(self, actions):
        world = self.world
        codes, rewards = world.step(actions)
        term, trunc = world.done(codes)
        obs = world.observation()
        info = self._info(codes, world.params, self.sim.judged.progress)
        done = term | trunc
        if done.any():
            final_obs = np.full(self.num_envs, None, dtype=object)
            for i in np.flatnonzero(done).tolist():
                final_obs[i] = {k: v[i] for k, v in obs.items()} if isinstance(obs, dict) else obs[i]
            reset_rows = self.sim.reset(done)
            obs = world.observe(reset_rows)
            info["final_obs"], info["_final_obs"] = final_obs, done
            info["final_info"], info["_final_info"] = self._final_info(info, done), done
            info["car"], info["_car"] = self._car_info(done)  # what a reset's info holds, for the reset envs
        return obs, rewards, term, trunc, info

    def _info(self, codes, params, progress):
        every = np.ones(self.num_envs, dtype=bool)
        info = {"episode_status": _STATUS_OBJ[codes], "_episode_status": every,
                "progress": progress.copy(), "_progress": every, "steps": self.sim.steps.copy(), "_steps": every}
        if params is not None:
            info["params"] = params
            info["_params"] = np.array([p is not None for p in params], dtype=bool)
        return info

    @staticmethod
    def _final_info(info, done):
        """The ended episodes' last info as Gymnasium's vector envs batch it: arrays, zero/None where `done` is
        False, each key with its `_key` mask."""
        final = {}
        for key in ("episode_status", "progress", "steps"):
            value = info[key]
            kept = np.full(len(done), None, dtype=object) if value.dtype == object else np.zeros_like(value)
            kept[done] = value[done]
            final[key], final["_" + key] = kept, done.copy()
        if "params" in info:
            params = np.full(len(done), None, dtype=object)
            for i in np.flatnonzero(done).tolist():
                params[i] = info["params"][i]
            final["params"], final["_params"] = params, done & info["_params"]
        return final
