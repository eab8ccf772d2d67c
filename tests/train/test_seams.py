"""The seams of `Trainer(collector=, logs=, learner=)` are written as Protocols (`train.seams`); this machine's
collection and logs, the cluster's and a taught model's offer every method with the same parameters, and so do the
learners (the agent itself, DAgger's), so any of them plugs into the trainer. `train/` has no import circle."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest

from racerlab.train import AgentLearner, Collection, IterationLogs, Learner, LocalCollection, TrainingLogs


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


def test_the_learners_offer_what_the_trainer_and_its_health_checks_call():
    from racerlab.agent.ppo import PPO
    from racerlab.agent.sac import SAC
    from racerlab.train.distill import DaggerLearner

    assert _members(Learner) == ["learn", "finite", "state_dict", "load_state_dict", "keep", "resume"]
    for learner in (AgentLearner, DaggerLearner):
        assert _mismatches(Learner, learner) == [], learner
    for agent in (PPO, SAC):  # what AgentLearner hands on to the agent (nothing to keep beside the checkpoint)
        assert [m for m in _mismatches(Learner, agent) if " is missing" not in m] == [], agent
        assert sorted(m for m in _mismatches(Learner, agent)) == [f"{agent.__name__}.keep is missing",
                                                                 f"{agent.__name__}.resume is missing"]
    for learner in (AgentLearner, DaggerLearner):  # the rate a rollback halves: read and set
        assert isinstance(learner.lr, property) and learner.lr.fset is not None, learner


def _train_imports(path: Path) -> tuple[set[str], set[str]]:
    """The `racerlab.train.*` modules a file imports, anywhere in it, and the private names it takes from them."""
    found, private = set(), set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        names = [node.module or ""] if isinstance(node, ast.ImportFrom) else (
            [a.name for a in node.names] if isinstance(node, ast.Import) else [])
        found |= {n for n in names if n.startswith("racerlab.train.")}
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("racerlab.train."):
            private |= {f"{node.module}.{a.name}" for a in node.names if a.name.startswith("_")}
    return found, private


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every import circle of `graph` ({module: modules it imports}), each from its smallest name."""
    found = []

    def visit(node, path):
        for nxt in sorted(graph.get(node, ())):
            if nxt == path[0]:
                found.append(path)
            elif nxt not in path and nxt > path[0]:
                visit(nxt, [*path, nxt])

    for start in sorted(graph):
        visit(start, [start])
    return found


def test_train_has_no_import_circle():
    """distill.py imported the loop and the loop imported distill.py for `train()` (issue 41)."""
    import racerlab.train as package

    here = Path(package.__file__).parent
    read = {f"racerlab.train.{p.stem}": _train_imports(p) for p in here.glob("*.py") if p.stem != "__init__"}
    graph = {module: imports for module, (imports, _) in read.items()}
    assert graph["racerlab.train.distill"] >= {"racerlab.train.loop"}  # the graph is read
    assert _circles(graph) == []
    # nor does one module of train/ call another's private helpers (distill.py took loop.py's `_ctrl_c_after`)
    assert [name for _, (_, private) in sorted(read.items()) for name in sorted(private)] == []
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]  # and a circle is found
