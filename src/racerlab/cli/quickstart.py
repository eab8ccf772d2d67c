"""`racerlab quickstart`: the main job on built-in defaults.

Creates the default model folder if it is missing, trains it on the default track for a few
minutes, drives a greedy lap with the best checkpoint and writes pictures of that lap and of the
training curve, then says where everything is.
"""

from __future__ import annotations

from pathlib import Path

DEFAULT_MODEL = Path("racerlab-out") / "quickstart-model"


def register(sub) -> None:
    p = sub.add_parser("quickstart", help="init → train → evaluate → pictures, on built-in defaults",
                       description="Create a model (if missing), train it on the default track, drive a lap "
                                   "with its best checkpoint and draw the results.")
    p.add_argument("--model", type=Path, default=DEFAULT_MODEL, help=f"model folder (default {DEFAULT_MODEL})")
    p.add_argument("--track", default=None, help="track name or path (default: the bundled default track)")
    p.add_argument("--minutes", type=float, default=3.0, help="training time in minutes (default 3)")
    p.add_argument("--max-speed", type=float, default=2.0, help="top speed of a new model's actions (default 2)")
    p.set_defaults(func=run)


def run(args) -> int:
    from racerlab.train import train
    from racerlab.train.folder import ModelFolder
    from racerlab.train.init import init_model

    folder = ModelFolder(args.model)
    if not folder.metadata_path.is_file():
        init_model(folder.path, track=args.track, max_speed=args.max_speed)
        print(f"created model folder {folder.path}")
    result = train(folder.path, minutes=args.minutes, tracks=[args.track] if args.track else None)
    lap = greedy_lap(folder)
    out = folder.path / "quickstart"
    out.mkdir(exist_ok=True)
    lap_png = out / "best_lap.png"
    curve_png = out / "training.png"
    draw_lap(lap, lap_png)
    draw_curve(result.history, curve_png)
    if lap["status"] == "lap_complete":
        print(f"best checkpoint {lap['checkpoint']}: greedy lap of {lap['track']} in {lap['lap_time']:.2f} s")
    else:
        print(f"best checkpoint {lap['checkpoint']}: greedy run ended {lap['status']} at {lap['progress']:.1f} %")
    print(f"results: model {folder.path} | lap picture {lap_png} | training curve {curve_png} | logs "
          f"{folder.path / 'logs'}")
    return 0


def greedy_lap(folder) -> dict:
    """Drive one greedy episode from the start line with the best checkpoint; returns its trajectory."""
    import numpy as np

    from racerlab.agent import make_agent
    from racerlab.sim import _kernels as K
    from racerlab.sim.core import StartRules
    from racerlab.sim.reward import RewardCaller, load_reward_function
    from racerlab.track import load as load_track
    from racerlab.train.rollout import World

    meta, cfg = folder.metadata(), folder.config()
    info = folder.resolve_checkpoint("best")
    state = folder.load_checkpoint(info)
    track = load_track(cfg.track.names[0])
    world = World(track, 1, meta, RewardCaller(load_reward_function(folder.reward_path)), cfg.run.observation,
                  StartRules(change_start=False, offset=cfg.track.start_offset), cfg.run.max_episode_steps, "aws", 0)
    agent = make_agent(world.observation.space, meta, folder.hyperparameters(), device="cpu")
    agent.load_state_dict(state["agent"])
    sim = world.sim
    sim.reset(start_ndist=cfg.track.start_offset)
    traj, speeds = [sim.pose[0, :2]], [0.0]
    active = np.ones(1, dtype=bool)
    while True:
        actions, _, _ = agent.act(world.observe(), greedy=True)
        codes, _ = world.step(actions, active)
        traj.append(sim.pose[0, :2])
        speeds.append(sim.speed[0])
        if sim.terminated_mask(codes)[0] or sim.truncated[0]:
            break
    status = K.STATUS_NAMES[int(codes[0])]
    return {"track": track, "checkpoint": info.name, "status": status, "steps": int(sim.steps[0]),
            "lap_time": sim.steps[0] * sim.dt, "progress": float(sim.params[0, K.MPROG]),
            "xy": np.array(traj), "speed": np.array(speeds)}


def draw_lap(lap: dict, path: Path) -> None:
    import numpy as np
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    from racerlab.track.plot import draw_track

    fig = Figure(figsize=(9, 7))
    ax = fig.add_subplot()
    draw_track(lap["track"], ax=ax, waypoint_numbers=False)
    xy = lap["xy"]
    segs = np.stack([xy[:-1], xy[1:]], axis=1)
    lc = LineCollection(segs, array=lap["speed"][1:], cmap="plasma", linewidths=2.5, zorder=5)
    ax.add_collection(lc)
    fig.colorbar(lc, ax=ax, label="speed (m/s)", shrink=0.7)
    what = f"lap {lap['lap_time']:.2f} s" if lap["status"] == "lap_complete" else \
        f"{lap['status']} at {lap['progress']:.1f} %"
    ax.set_title(f"{lap['track'].name}: greedy run of {lap['checkpoint']} — {what}")
    fig.savefig(path, dpi=120, bbox_inches="tight")


def draw_curve(history: list[dict], path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 4.5))
    ax = fig.add_subplot()
    if history:
        it = [h["iteration"] for h in history]
        ax.plot(it, [h["charts/completion"] for h in history], label="training completion (%)")
        ax.plot(it, [h["eval/mean_progress"] or 0 for h in history], label="evaluation progress (%)")
        ax2 = ax.twinx()
        ax2.plot(it, [h["charts/mean_reward"] for h in history], color="tab:green", alpha=0.6, label="mean reward")
        ax2.set_ylabel("mean episode reward")
        ax2.legend(loc="lower right")
    ax.set_xlabel("iteration")
    ax.set_ylabel("%")
    ax.set_ylim(0, 105)
    ax.legend(loc="upper left")
    ax.set_title("training progress")
    fig.savefig(path, dpi=120, bbox_inches="tight")
