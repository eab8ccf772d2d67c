"""The seams of `Trainer(collector=, logs=)` are written as Protocols (`train.seams`); this machine's collection
and logs and the cluster's both offer every method with the same parameters, so either plugs into the trainer."""

from __future__ import annotations

import inspect

import pytest

from racerlab.train import Collection, IterationLogs, LocalCollection, TrainingLogs


def _members(protocol) -> list[str]:
    return [n for n, v in vars(protocol).items() if inspect.isfunction(v) and not n.startswith("_")]


def _mismatches(protocol, impl) -> list[str]:
    out = []
    for name in _members(protocol):
        want = list(inspect.signature(getattr(protocol, name)).parameters.values())
        have = getattr(impl, name, None)
        if have is None:
            out.append(f"{impl.__name__}.{name} is missing")
            continue
        got = list(inspect.signature(have).parameters.values())
        if [(p.name, p.kind, p.default) for p in got] != [(p.name, p.kind, p.default) for p in want]:
            wanted = inspect.signature(getattr(protocol, name))
            out.append(f"{impl.__name__}.{name}{inspect.signature(have)} != {name}{wanted}")
    return out


def _cluster():
    pytest.importorskip("ray")
    from racerlab.cluster.training import ClusterCollection, WorkerLogs

    return ClusterCollection, WorkerLogs


def _taught():
    from racerlab.train.distill import PairedCollection

    return PairedCollection, TrainingLogs


@pytest.mark.parametrize("side", ["local", "cluster", "taught"])
def test_the_collections_and_logs_offer_what_the_trainer_calls(side):
    pick = {"local": lambda: (LocalCollection, TrainingLogs), "cluster": _cluster, "taught": _taught}
    collection, logs = pick[side]()
    assert _members(Collection) == ["collect", "before_iteration", "state", "restore", "metrics", "close"]
    assert _members(IterationLogs) == ["write_iteration", "append_metrics", "truncate", "disk_bytes", "close"]
    assert _mismatches(Collection, collection) == []
    assert _mismatches(IterationLogs, logs) == []


def test_a_collection_missing_a_method_or_taking_other_parameters_is_named():
    class Partial:
        def collect(self, agent, target_episodes, max_steps):  # no first_episode_number, deadline, tick
            pass

        def state(self) -> dict:
            return {}

    found = _mismatches(Collection, Partial)
    assert found[0].startswith("Partial.collect(self, agent, target_episodes, max_steps) != collect(")
    assert "Partial.before_iteration is missing" in found and "Partial.state" not in " ".join(found)
    assert not isinstance(Partial(), Collection) and isinstance(object.__new__(LocalCollection), Collection)
