"""`racerlab init`: a working model folder with AWS-default files and racerlab's run settings."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from racerlab.errors import RacerlabError
from racerlab.model.config import TrackSettings, TrainingConfig
from racerlab.model.folder import ModelFolder
from racerlab.model.hyperparameters import Hyperparameters
from racerlab.model.metadata import ContinuousActions, ModelMetadata, default_discrete_actions
from racerlab.reward import EXAMPLE_REWARDS
from racerlab.spec import MAX_SPEED, MAX_STEERING_DEG, MIN_SPEED, RaceConfig

OWN_TEACHER = "teacher"  # a camera model's features teacher, a folder inside it (racerlab.train.distill)
# `init --race head_to_bot`: DRfC's template (DR_H2B_NUMBER_OF_BOT_CARS=3), the simulator's bot defaults
HEAD_TO_BOT_CARS = 3
# `init --race object_avoidance`: three fixed boxes that pass the console's rules (first >= 7 %, last <= 90 %,
# gaps >= 13 % of the lap), alternating lanes
OBJECT_AVOIDANCE_POSITIONS = ((0.25, 1), (0.5, -1), (0.75, 1))
SENSORS = {
    "features": (("FEATURES",), "MLP"),
    "camera": (("FRONT_FACING_CAMERA",), "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"),
    "stereo": (("STEREO_CAMERAS",), "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"),
    "lidar": (("FRONT_FACING_CAMERA", "LIDAR"), "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"),
}


def make_metadata(sensor: str = "features", action_space: str = "discrete", algorithm: str = "clipped_ppo",
                  max_speed: float = 1.0) -> ModelMetadata:
    """AWS console defaults (facts §5) for the chosen sensor; `max_speed` scales the speeds."""
    if sensor not in SENSORS:
        raise RacerlabError(f"unknown sensor {sensor!r}; choose one of {', '.join(SENSORS)}")
    if not MIN_SPEED <= max_speed <= MAX_SPEED:
        raise RacerlabError(f"max speed must be within [{MIN_SPEED}, {MAX_SPEED}] m/s, got {max_speed}")
    if algorithm == "sac" and action_space != "continuous":
        raise RacerlabError("SAC needs a continuous action space: add --action-space continuous")
    sensors, network = SENSORS[sensor]
    if action_space == "discrete":
        actions = default_discrete_actions(max_speed=max_speed)
    elif action_space == "continuous":
        actions = ContinuousActions(-MAX_STEERING_DEG, MAX_STEERING_DEG, min(1.0, max_speed / 2), max(max_speed, 0.2))
    else:
        raise RacerlabError(f"action space must be discrete or continuous, got {action_space!r}")
    return ModelMetadata(actions, sensors, network, algorithm, 5.0)


# training presets of `racerlab init --preset NAME`: training.toml settings laid over the defaults
PRESETS = {
    # train over 8 generated circuits, drawn anew every 5 iterations, to drive tracks never seen
    "generalise": {"track": {"generated": 8, "regenerate_every": 5}},
}


# `--preset generalise --tracks-from DIR`: the generalist recipe (docs/learner.md, "A camera model for any
# track"). The training set is every layout of DIR outside a held-out set; the reward follows no line.
GENERALIST_REWARD = "pace"
GENERALIST_TRACK = "reInvent2019_track"  # trained on and evaluated after each round, when DIR has it
# a camera model's part: its features teacher drives every training track at once and trains longer; the camera
# student drives `at_once` tracks at a time (a camera world's raster is ~170 MB and ~5 s to build), two cars each,
# under randomised light, camera pose, exposure, noise and actuation
GENERALIST_CAMERA = {
    "teacher": {"minutes": 12.0, "iterations": 200},
    "track": {"at_once": 14, "regenerate_every": 3},
    "run": {"num_cars": 28},
    "randomise": {"camera_noise": 4.0, "blur": 1.0, "exposure": 0.25, "gamma": 0.25, "lighting": True,
                  "pose_yaw_deg": 2.0, "pose_pitch_deg": 2.0, "pose_shift_m": 0.02, "latency_steps": 1,
                  "latency_varies": True, "steering_gain": 0.1, "throttle_gain": 0.1},
}


@dataclass(frozen=True)
class TrainingSet:
    """The tracks a generalist trains on and the ones held out from it, drawn from one folder (`training_set`)."""

    folder: Path
    names: tuple[str, ...]  # trained on; the first is the in-training evaluation's track
    held_out: tuple[str, ...]  # never trained on: no file of their layouts is in `names`
    seed: int

    def header(self) -> str:
        return (f"# training set: {len(self.names)} layouts of {self.folder}; held out (never trained on, seed "
                f"{self.seed}): {', '.join(self.held_out)}\n")


def training_set(folder, held_out: int = 20, seed: int = 0, track: str | None = None) -> TrainingSet:
    """`held_out` layouts of `folder` drawn at random (seeded) and kept out, and one track of every other closed
    layout to train on (`track.layouts`); `track` (default GENERALIST_TRACK where `folder` has it) is trained on,
    first, and never held out."""
    from racerlab import track as tracks
    from racerlab.track.layouts import folder_layouts, held_out_tracks, layout_shape, same_layout, training_tracks

    folder = Path(folder)
    layouts = folder_layouts(folder)
    first = track or (GENERALIST_TRACK if GENERALIST_TRACK in layouts else None)
    held = held_out_tracks(folder, held_out, exclude=(first,) if first else (), seed=seed)
    train = training_tracks(folder, held)
    if first:
        shape = layout_shape(tracks.load(str(layouts.get(first, first))))
        train = [p for p in train if not same_layout(layout_shape(tracks.load(str(p))), shape)]
        names = (_track_name(layouts.get(first, first)), *(_track_name(p) for p in train))
    else:
        names = tuple(_track_name(p) for p in train)
    if not names:
        raise RacerlabError(f"{folder}: all its {held_out} closed layouts held out, none left to train on; lower "
                            "--held-out or add tracks")
    return TrainingSet(folder, names, tuple(p.stem for p in held), seed)


def _track_name(path) -> str:
    """A track as training.toml names it: its name where that finds this very file, else its path."""
    from racerlab.track.registry import catalogue

    p = Path(path)
    if p.suffix and p.is_file():
        found = catalogue().get(p.stem)
        return p.stem if found is not None and found.resolve() == p.resolve() else str(p.resolve())
    return str(path)


def apply_generalist(cfg: TrainingConfig, sensor: str, tset: TrainingSet) -> TrainingConfig:
    """The generalist's training.toml: its training set, and for a camera model GENERALIST_CAMERA."""
    cfg = replace(cfg, track=replace(cfg.track, names=tset.names, generated=0))
    if sensor != "camera":
        return replace(cfg, run=replace(cfg.run, num_cars=max(cfg.run.num_cars, len(tset.names))))
    for section, values in GENERALIST_CAMERA.items():
        cfg = replace(cfg, **{section: replace(getattr(cfg, section), **values)})
    return cfg


def apply_preset(cfg: TrainingConfig, preset: str | None, sensor: str) -> TrainingConfig:
    if not preset:
        return cfg
    if preset not in PRESETS:
        raise RacerlabError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
    for section, values in PRESETS[preset].items():
        cfg = replace(cfg, **{section: replace(getattr(cfg, section), **values)})
    if preset == "generalise" and sensor == "lidar":
        # AWS tracks are flat paint: a lidar sees nothing there unless the borders count as walls
        cfg = replace(cfg, run=replace(cfg.run, observation="lidar:walls"))
    return cfg


def init_model(path, track: str | None = None, sensor: str = "features", action_space: str = "discrete",
               algorithm: str = "clipped_ppo", max_speed: float = 1.0, num_cars: int | None = None,
               best_model_metric: str | None = None, force: bool = False, race: str = "time_trial",
               preset: str | None = None, teacher: bool = True, tracks_from=None, held_out: int = 20,
               held_out_seed: int = 0) -> ModelFolder:
    """A new model folder. With `preset="generalise"` and `tracks_from` (a folder of AWS tracks) the model trains on
    every layout of that folder outside `held_out` ones drawn with `held_out_seed` (`training_set`; training.toml's
    header names the held-out tracks), with the `pace` reward and, for a camera model, GENERALIST_CAMERA."""
    if tracks_from is not None and preset != "generalise":
        raise RacerlabError(f"--tracks-from {tracks_from}: a training set of many tracks goes with --preset "
                            "generalise; add it, or give one track with --track")
    folder = ModelFolder(path)
    existing = [p for p in folder.model_files if p.exists()]
    if existing and not force:
        raise RacerlabError(f"{folder.path}: already holds {existing[0].name}; use another folder or --force")
    meta = make_metadata(sensor, action_space, algorithm, max_speed)
    hp = Hyperparameters()
    if algorithm == "sac":
        hp = hp.replace(num_episodes_between_training=1)  # DRoA's SAC default
    cfg = TrainingConfig()
    if track:
        from racerlab import track as tracks

        tracks.load(track)  # fail now, with the track's own message, not at training time
        cfg = replace(cfg, track=TrackSettings(names=(track,)))
    if num_cars:
        cfg = replace(cfg, run=replace(cfg.run, num_cars=num_cars))
    if best_model_metric:
        cfg = replace(cfg, evaluation=replace(cfg.evaluation, best_model_metric=best_model_metric))
    if sensor != "features":
        # pixels cost more per step; fewer cars keep an iteration's memory and time moderate
        cfg = replace(cfg, run=replace(cfg.run, num_cars=num_cars or 16))
    if sensor == "camera" and algorithm == "clipped_ppo" and teacher:
        # learns a features teacher's actions first (racerlab.train.distill): near the limit in minutes, not hours
        cfg = replace(cfg, teacher=replace(cfg.teacher, model=OWN_TEACHER))
    cfg = apply_preset(_with_race(cfg, race), preset, sensor)
    reward, header = EXAMPLE_REWARDS[race].read_text(), _TOML_HEADER
    if tracks_from is not None:
        from racerlab.reward import reward_source

        tset = training_set(tracks_from, held_out, held_out_seed, track)
        cfg = apply_generalist(cfg, sensor, tset)
        reward, header = reward_source(GENERALIST_REWARD), tset.header() + _TOML_HEADER
        # an iteration starts one episode per car at most as many as it collects: every car drives in each
        hp = hp.replace(num_episodes_between_training=max(hp.num_episodes_between_training, cfg.run.num_cars))
    folder.write_reward(reward)
    folder.write_metadata(meta)
    folder.write_hyperparameters(hp)
    folder.write_config(cfg, header)
    return folder


def _with_race(cfg: TrainingConfig, race: str) -> TrainingConfig:
    if race not in EXAMPLE_REWARDS:
        raise RacerlabError(f"race must be one of {', '.join(EXAMPLE_REWARDS)}, got {race!r}")
    if race == "object_avoidance":
        return replace(cfg, race=RaceConfig(type=race, object_positions=OBJECT_AVOIDANCE_POSITIONS))
    if race == "head_to_bot":
        return replace(cfg, race=RaceConfig(type=race, number_of_bot_cars=HEAD_TO_BOT_CARS))
    if race == "head_to_model":  # self-play: the cars race in pairs, each the other's object
        return replace(cfg, race=RaceConfig(type=race))
    return cfg


_TOML_HEADER = """\
# racerlab run settings for this model (the AWS files beside it hold the reward function, action
# space and hyperparameters). Command-line flags of `racerlab train` override these values.
#   [track]  names: one or more tracks (bundled names, your own, or paths); cars are spread over them
#            reverse / alternate_direction / change_start / round_robin_advance / start_offset: as DRfC
#   [run]    num_cars in parallel, seed, device (auto|cpu|cuda), threads (0 = auto: all cores for
#            camera networks, 1 for vector ones),
#            observation ("" follows model_metadata.json), look: the camera's world (aws: the AWS
#            simulator's | classic: racerlab's earlier one), reward_order (aws|after_action),
#            max_steps_per_iteration (AWS: 10000), max_episode_steps, reward_budget_s (0 = no limit)
#   [stop]   minutes, episodes, iterations (0 = no limit)
#   [evaluation] episodes after each iteration, best_model_metric (progress|reward|laptime)
#   [logs]   simtrace_every: log every k-th training episode; plain_iterations: the newest iterations kept
#            as plain CSV (deepracer-utils reads those), older ones gzipped; max_mb: the budget of
#            training-simtrace/ + metrics/, past which the oldest gzipped iterations are thinned (0 = none);
#            compress: gzip all
#   [track]  generated = N trains on N generated circuits (names then holds the evaluation track), drawn
#            anew every regenerate_every iterations, within the generated_* length / width / radius ranges
#   [randomise] domain randomisation for the physical car (all off by default; docs/learner.md):
#            camera_noise, blur, exposure, gamma, lighting, pose_yaw_deg, pose_pitch_deg, pose_shift_m,
#            lidar_noise_m, latency_steps (0-2), steering_gain, throttle_gain; speed_scale and top_speed
#            map speeds relative to the action space's top, as the car does; evaluation: also in eval episodes
#   [race]   DRfC's race settings: type (time_trial|object_avoidance|head_to_bot|head_to_model: cars race in
#            pairs, each the other's object), number_of_obstacles,
#            obstacle_type, randomize_obstacle_locations, object_positions ([fraction of the lap, lane 1 inner |
#            -1 outer]), min_distance_between_obstacles (% of the lap), number_of_bot_cars,
#            randomize_bot_car_locations, bot_car_speed (m/s), is_lane_change, lower_/upper_lane_change_time (s),
#            lane_change_distance (m), min_distance_between_bot_cars (m), penalty_seconds (a bot's wait after
#            it ran into the car)
#   [[worker]] (racerlab train --workers): one table per rollout worker, changing its settings, e.g.
#            track.names = ["lab_oval"], track.reverse = true, race.type = "object_avoidance"

"""
