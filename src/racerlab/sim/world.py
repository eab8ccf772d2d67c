"""`World`: one track's batched simulator with what every driver of it needs, in one place.

A world is a `Simulator` plus the observation, the model's action mapping (the discrete lookup or the
continuous rescale of `model_metadata`), the AWS params builder and the reward calls. The Gymnasium
adapters (`racerlab.sim.env`), training rollouts (`racerlab.train.rollout`) and evaluation
(`racerlab.evaluate.runner`, `racerlab.train.evaluation`) all drive one:

    >>> world = World("reInvent2019_track", 64, metadata, reward_function, "features", seed=0)
    >>> obs = world.observe()
    >>> codes, rewards = world.step(actions)          # actions of every car (or of `active` ones)
    >>> world.sim.judged.progress, world.sim.state.speed
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from racerlab.model.metadata import DiscreteActions, as_model_metadata, split_observation_name
from racerlab.reward import as_reward_caller
from racerlab.sim import _kernels as K
from racerlab.sim.core import Simulator, StartRules
from racerlab.sim.observations import make_observation, observation_name_for
from racerlab.sim.params import ParamsBuilder
from racerlab.sim.randomise import CAMERA_KEYS, Actuation, RandomisedObservation, as_settings, make_rng
from racerlab.spec import DEFAULT_SIMULATOR, CarParams, car_params


def _start_rules(start):
    if start is None or isinstance(start, StartRules):
        return start
    return StartRules(**start)


def car_for(car, metadata=None) -> CarParams:
    """The car a world drives: `car` is a `CarParams` (as is), None (the default simulator's car), a simulator name,
    or a `[car]` table as a dict (`simulator` and constants to override); the model's `version` picks the car
    within the simulator (`spec.car_params`)."""
    if isinstance(car, CarParams):
        return car
    version = "5" if metadata is None else as_model_metadata(metadata).version  # spec.control_of reads any number
    if car is None:
        return car_params(DEFAULT_SIMULATOR, version)
    if isinstance(car, str):
        return car_params(car, version)
    if hasattr(car, "params"):  # model.config.CarSettings
        return car.params(version)
    table = dict(car)
    return car_params(table.pop("simulator", DEFAULT_SIMULATOR), table.pop("version", version), **table)


class World:
    """`num_cars` cars on `track` with an observation, the action mapping and the reward.

    `metadata` is a `ModelMetadata`, its dict or path, or None (the console's default discrete space);
    `reward` a `RewardCaller`, a callable, a path, or None (reward 0 and no params built: the fastest
    path). `observation` names it ("features", "camera", ...); None follows the model's sensors, or
    is "features" when no metadata is given either. `car` is the car (`car_for`: a `CarParams`, a simulator
    name, a `[car]` table; None: the default simulator's car for the model's version); `start` a `StartRules`
    or its keyword dict; `race` a `RaceConfig`, its `[race]` table as a dict, or a race type name
    ("object_avoidance": 6 evenly spaced boxes), None for a time trial. With `keep_params`, `params` holds
    each car's params dict of the last step (None where no reward was called). `randomise`
    (`RandomiseSettings` or its keyword dict) perturbs actions and observations as the physical car would
    (`racerlab.sim.randomise`); None or all defaults leave the plain path untouched. `look` is how the world
    looks to a camera (training.toml's `run.look`: "aws" or "classic", `sim.sensors.look.LOOKS`); observations
    without a camera ignore it.
    """

    def __init__(self, track, num_cars: int = 1, metadata=None, reward=None, observation: str | None = None, *,
                 car=None, start=None, max_episode_steps: int = 10_000, reward_order: str = "aws",
                 seed: int | None = None, keep_params: bool = False, race=None, sim: Simulator | None = None,
                 randomise=None, look: str = "aws"):
        # `sim`: drive an existing simulator (another model's cars in the same world); track, num_cars, car,
        # start, max_episode_steps, reward_order, seed and race are then its own
        self.sim = sim or Simulator(track, num_cars, car_for(car, metadata), start=_start_rules(start),
                                    max_episode_steps=max_episode_steps, reward_order=reward_order, seed=seed,
                                    race=race)
        self.metadata = as_model_metadata(metadata)
        if observation is None and metadata is None:
            observation = "features"
        if look != "aws":
            observation = with_look(observation or observation_name_for(self.metadata), look)
        self.randomise = as_settings(randomise)
        self.actuation = None
        if self.randomise is None:
            self.observation = make_observation(observation, self.sim, self.metadata)
        else:
            self._randomised(observation, seed)
        self.reward = as_reward_caller(reward)
        self.builder = ParamsBuilder(self.sim) if self.reward is not None else None
        self.keep_params = keep_params
        self.params: list[dict | None] | None = None
        self.discrete = isinstance(self.metadata.actions, DiscreteActions)

    def _randomised(self, observation, seed) -> None:
        r, rng = self.randomise, make_rng(seed)
        if r.lighting:
            observation = with_option(observation or observation_name_for(self.metadata), "dr")
        self.observation = RandomisedObservation(make_observation(observation, self.sim, self.metadata), self.sim, r,
                                                 rng)
        self.actuation = Actuation(r, self.sim.num_cars, self.metadata.actions.top_speed, rng)

    @property
    def num_cars(self) -> int:
        return self.sim.num_cars

    @property
    def state(self):
        """The cars now, by name (`Simulator.state`)."""
        return self.sim.state

    @property
    def action_space(self) -> gym.Space:
        """`Discrete(n)` for a discrete action list, else `Box(-1, 1, (2,))` ([steering, speed])."""
        acts = self.metadata.actions
        if self.discrete:
            return gym.spaces.Discrete(acts.n)
        return gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)

    def observe(self, rows=None):
        """The batch observation; observations that can update just `rows` (the cars whose observation
        is needed, e.g. after a partial reset) skip the others, whose rows then hold stale values."""
        if rows is not None and getattr(self.observation, "partial_update", False):
            return self.observation(np.asarray(rows, dtype=np.int64))
        return self.observation()

    def commands(self, actions) -> tuple[np.ndarray, np.ndarray]:
        """Commanded (steering °, speed m/s) for a batch of actions: indices into the discrete action list,
        or [steering, speed] in [-1, 1] rescaled to the continuous ranges."""
        acts = self.metadata.actions
        if self.discrete:
            return acts.lookup(np.asarray(actions).reshape(-1))
        return acts.rescale(np.asarray(actions, dtype=np.float64).reshape(-1, 2))

    def step(self, actions, active=None) -> tuple[np.ndarray, np.ndarray]:
        """One step of every car, or of the cars in the mask `active` (whose actions alone are given).

        Returns (status codes, rewards) for all cars; the reward is 0 where a car was not stepped or took
        its prepare step. The step-cap flags are in `sim.truncated`, the judged pose in `sim.judged`.
        """
        sim = self.sim
        steer, speed = self.commands(actions)
        if active is not None:
            idx = np.flatnonzero(active)
            steer_all = np.zeros(sim.num_cars)
            speed_all = np.zeros(sim.num_cars)
            steer_all[idx], speed_all[idx] = steer, speed
            steer, speed = steer_all, speed_all
        chosen = None
        if self.actuation is not None:
            chosen = (steer, speed)  # the reward sees the model's action, as on AWS; the car drives the applied one
            steer, speed = self.actuation(steer, speed, sim.ctr[:, K.KSTEPS], active)
        codes = sim.step(steer, speed, active).copy()
        return codes, self.rewards(codes, active, chosen)

    def rewards(self, codes, active=None, chosen=None) -> np.ndarray:
        """The rewards of the last step (0 where a car was not stepped, took its prepare step or no reward
        function is set), for the cars in `active` (all by default); `params` keeps their dicts when asked.
        `chosen` (steer, speed) are the model's commands when the car drove perturbed ones (randomisation)."""
        sim = self.sim
        rewards = np.zeros(sim.num_cars)
        self.params = None
        if self.reward is not None:
            stepped = codes != K.STATUS_PREPARE
            run = np.flatnonzero(stepped if active is None else stepped & active)
            kept = [] if self.keep_params else None
            if run.size:
                rewards[run] = self.reward(self.builder.each(run, actions=chosen), run, kept)
            if kept is not None:
                self.params = [None] * sim.num_cars
                for j, i in enumerate(run.tolist()):
                    self.params[i] = kept[j]
        return rewards

    def done(self, codes) -> tuple[np.ndarray, np.ndarray]:
        """(terminated, truncated) masks after a step that returned `codes`."""
        return self.sim.terminated_mask(codes), self.sim.truncated.copy()


def with_option(name: str, option: str) -> str:
    """An observation name with `option` added after its colon (``camera`` → ``camera:dr``)."""
    base, options = split_observation_name(name)
    return name if option in options else f"{base}:{','.join((*options, option))}"


def with_look(name: str, look: str) -> str:
    """An observation name with the camera look `look` as its option (``camera`` → ``camera:classic``); a name
    without a camera is returned as it is."""
    if split_observation_name(name)[0].split("+")[0] not in CAMERA_KEYS:
        return name
    return with_option(name, look)
