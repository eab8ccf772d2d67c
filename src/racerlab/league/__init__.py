"""`racerlab league`: a race server for many racers that is fair, cheap and says why.

    >>> from racerlab.league import League
    >>> league, password = League.create("club")           # the store and its first admin (`league init`)
    >>> admin = league.local_admin()
    >>> league.create_race(admin, "may-cup", {"track": "reInvent2019_track", "laps": 3, "timing": "best_lap"})
    >>> ana = league.accept_invite(league.invite(admin, "ana").code, "a long password")
    >>> league.submit(ana, "may-cup", "ana-model.tar.gz").status        # 'queued'
    >>> pool = start_workers("club", workers=2)            # evaluations in local processes
    >>> league.standings(admin, "may-cup").rows

Parts: `store` (database, migrations, the league folder), `tables` (the SQLAlchemy models), `people` (roles,
passwords, invites, tokens, throttling), `rules` (a race's frozen rules and their hash), `races` (race options,
times), `service` (`League`: the API the web pages and the command line call), `submissions` (its submission,
result and standings calls), `convert` (uploads to safetensors in a locked-down child), `queue` (claims, leases,
retries), `evaluation` (a stored model raced under the rules: a pure function), `worker` (local worker processes),
`ray_pool` (evaluations on a Ray cluster),
`scoring` (timing methods, the leaderboard order), `seasons` (points per place, overall standings), `finals`
(head-to-model finals of a race's top racers), `audit` (the append-only log), `views` (what calls return).
See docs/league.md.
"""

import importlib

# each name from the module that holds it, on first use: `racerlab --help` and `racerlab league race create` read
# the rules' choices (`league.rules`) without importing the service and, through it, the simulator and torch
_WHERE = {"ROLES": "people", "Actor": "people", "RaceOptions": "races", "Rules": "rules", "League": "service",
          "LeagueError": "store", "Store": "store"}

__all__ = ["ROLES", "Actor", "League", "LeagueError", "RaceOptions", "Rules", "Store", "start_ray_workers",
           "start_workers"]


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'racerlab.league' has no attribute {name!r}")
    return getattr(importlib.import_module(f"racerlab.league.{_WHERE[name]}"), name)


def start_workers(folder, url: str | None = None, workers: int = 1, **options):
    """Start `workers` local evaluation processes on the league in `folder` (see `racerlab.league.worker.WorkerPool`);
    call `.stop()` on the answer to end them."""
    from racerlab.league.worker import WorkerPool

    return WorkerPool(folder, url, workers, **options).start()


def start_ray_workers(folder, url: str | None = None, address: str = "", workers: int | None = None, **options):
    """Send the league's evaluations to the Ray cluster at `address`, `workers` at a time (default: its CPUs; see
    `racerlab.league.ray_pool.RayPool`); call `.stop()` on the answer to end them."""
    from racerlab.league.ray_pool import RayPool

    return RayPool(folder, url, address, workers, **options).start()
