"""Submissions: converted to data, hashed, counted in the insert's transaction, identical ones answered once."""

from __future__ import annotations

import multiprocessing as mp
import tarfile
import threading

import pytest
from sqlalchemy import func, select

from racerlab.league import League, LeagueError
from racerlab.league.tables import Submission
from tests.league.conftest import features_model, racer


@pytest.fixture
def cup(league, admin, straight):
    league.create_race(admin, "cup", {"track": str(straight), "max_submissions": 3})
    return "cup"


def _pack(folder, out):
    with tarfile.open(out, "w:gz") as tar:
        tar.add(folder, arcname=folder.name)
    return out


def test_a_submission_is_queued_with_its_place_hash_and_rules(league, admin, cup, straight, tmp_path):
    ana = racer(league, admin, "ana")
    sub = league.submit(ana, cup, features_model(tmp_path / "m", straight).path)
    assert (sub.status, sub.number, sub.position, sub.source, sub.checkpoint) == (
        "queued", 1, 1, "racerlab", "1_Step-100.pt")
    assert sub.rules_hash == league.race(ana, cup).rules_hash and len(sub.model_hash) == 64
    stored = league.store.model_dir(sub.model_hash)
    assert sorted(p.name for p in stored.iterdir()) == ["model.json", "model_metadata.json", "training.toml",
                                                        "weights.safetensors"]
    assert not list((league.store.folder / "uploads").iterdir())  # the conversion's work folder is gone
    assert league.race(ana, cup).submissions_used == 1
    actions = [e.action for e in league.audit(admin)]
    assert actions[-1] == "submission.create"


def test_the_same_model_as_a_folder_or_an_archive_is_one_model(league, admin, cup, straight, tmp_path):
    ana = racer(league, admin, "ana")
    folder = features_model(tmp_path / "m", straight).path
    first = league.submit(ana, cup, folder)
    again = league.submit(ana, cup, _pack(folder, tmp_path / "m.tar.gz"))
    assert again.duplicate and again.id == first.id and again.model_hash == first.model_hash
    assert "identical to your submission #1" in again.note and "no submission was used" in again.note
    assert league.race(ana, cup).submissions_used == 1
    other = league.submit(ana, cup, features_model(tmp_path / "m2", straight, seed=1).path)
    assert not other.duplicate and other.number == 2 and other.model_hash != first.model_hash


def test_the_racer_picks_the_checkpoint_best_by_default(league, admin, cup, straight, tmp_path):
    from racerlab.model import ModelFolder, TrainingState

    ana = racer(league, admin, "ana")
    folder = features_model(tmp_path / "m", straight, seed=0, iteration=1)
    other = features_model(tmp_path / "n", straight, seed=5, iteration=2)
    state = other.load_state(other.resolve_checkpoint(2))
    ModelFolder(folder.path).save_state(TrainingState(state.agent, state.metadata, iteration=2, train_steps=200))
    best = league.submit(ana, cup, folder.path)  # the index still names iteration 1 as the best
    second = league.submit(ana, cup, folder.path, checkpoint="2")
    assert (best.checkpoint, second.checkpoint) == ("1_Step-100.pt", "2_Step-200.pt")
    assert best.model_hash != second.model_hash
    with pytest.raises(LeagueError, match="no checkpoint for iteration 7"):
        league.submit(ana, cup, folder.path, checkpoint="7")


def test_the_limit_is_checked_before_the_upload_is_read(league, admin, cup, straight, tmp_path):
    ana = racer(league, admin, "ana")
    for k in range(3):
        league.submit(ana, cup, features_model(tmp_path / f"m{k}", straight, seed=k).path)
    with pytest.raises(LeagueError, match="used all 3 submissions") as err:
        league.submit(ana, cup, tmp_path / "not even a model")
    assert err.value.status == 409
    league.update_race(admin, cup, max_submissions=4)
    assert league.submit(ana, cup, features_model(tmp_path / "m3", straight, seed=3).path).number == 4


def _insert_in_child(folder, url, actor, race, conv, barrier, out):
    league = League.open(folder, url)
    barrier.wait()
    try:
        out.put(("ok", league.enter(actor, race, conv, _now())))
    except LeagueError as exc:
        out.put(("refused", str(exc)))


def _now():
    from racerlab.league.tables import utcnow

    return utcnow()


def _converted(league, model, tmp):
    from racerlab.league.convert import convert_upload, store_converted

    conv = convert_upload(model, tmp)
    store_converted(conv, league.store.folder / "models")
    return conv


def test_two_simultaneous_submissions_at_the_limit_let_exactly_one_in(league, admin, cup, straight, tmp_path):
    """Two processes insert at the same moment with one submission left (DRoA let both through)."""
    ana = racer(league, admin, "ana")
    for k in range(2):
        league.submit(ana, cup, features_model(tmp_path / f"m{k}", straight, seed=k).path)
    convs = [_converted(league, features_model(tmp_path / f"r{k}", straight, seed=10 + k).path, tmp_path / f"c{k}")
             for k in range(2)]
    ctx = mp.get_context("spawn")
    barrier, out = ctx.Barrier(2), ctx.Queue()
    procs = [ctx.Process(target=_insert_in_child, args=(league.store.folder, None, ana, cup, c, barrier, out))
             for c in convs]
    for p in procs:
        p.start()
    results = sorted(out.get(timeout=120)[0] for _ in procs)
    for p in procs:
        p.join(30)
    assert results == ["ok", "refused"]
    with league.store.read() as s:
        assert s.scalar(select(func.count()).select_from(Submission)) == 3


def test_many_threads_at_the_limit_never_pass_it(league, admin, cup, straight, tmp_path):
    ana = racer(league, admin, "ana")
    convs = [_converted(league, features_model(tmp_path / f"r{k}", straight, seed=20 + k).path, tmp_path / f"c{k}")
             for k in range(6)]
    barrier, results = threading.Barrier(len(convs)), []

    def go(conv):
        barrier.wait()
        try:
            results.append(league.enter(ana, cup, conv, _now()).number)
        except LeagueError:
            results.append("refused")

    threads = [threading.Thread(target=go, args=(c,)) for c in convs]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert sorted(r for r in results if r != "refused") == [1, 2, 3] and results.count("refused") == 3


def test_outside_the_window_nothing_is_read(league, admin, straight, tmp_path):
    league.create_race(admin, "later", {"track": str(straight), "opens": "+1h"})
    with pytest.raises(LeagueError, match="opens at") as err:
        league.submit(admin, "later", tmp_path / "anything")
    assert err.value.status == 409


def test_a_racer_sees_only_their_own_submissions(league, admin, cup, straight, tmp_path):
    ana, bo = racer(league, admin, "ana"), racer(league, admin, "bob")
    sub = league.submit(ana, cup, features_model(tmp_path / "m", straight).path)
    with pytest.raises(LeagueError, match="no submission") as err:
        league.submission(bo, sub.id)
    assert err.value.status == 404
    with pytest.raises(LeagueError, match="no submission"):
        league.submission_file(bo, sub.id, "simtrace")
    assert [s.id for s in league.submissions(bo)] == []
    assert [s.id for s in league.submissions(ana, cup)] == [sub.id]
    assert [s.id for s in league.submissions(admin, everyone=True)] == [sub.id]
    with pytest.raises(LeagueError, match="may not submission view any"):
        league.submissions(ana, everyone=True)


def test_a_failed_evaluation_uses_no_submission_and_its_retry_gets_in_at_the_limit(league, admin, straight, tmp_path):
    from racerlab.league import queue

    league.create_race(admin, "one", {"track": str(straight), "laps": 1, "time_cap_s": 30, "video": False,
                                      "max_submissions": 1})
    ana = racer(league, admin, "ana")
    model = features_model(tmp_path / "m", straight, seed=1).path
    sub = league.submit(ana, "one", model)
    claim = queue.claim(league.store, "w1")
    queue.finish(league.store, claim, "failed", "the league's disk filled up", {})  # the league's fault
    assert league.race(ana, "one").submissions_used == 0
    again = league.submit(ana, "one", model)  # the retry: queued again, at the limit of 1
    assert again.id == sub.id and again.status == "queued" and league.race(ana, "one").submissions_used == 1
    claim = queue.claim(league.store, "w1")
    queue.finish(league.store, claim, "failed", "the league's disk filled up", {})
    other = league.submit(ana, "one", features_model(tmp_path / "n", straight, seed=2).path)  # the freed place
    assert other.id != sub.id and league.race(ana, "one").submissions_used == 1
    with pytest.raises(LeagueError, match="used all 1 submissions"):  # the old one's retry would be a second
        league.submit(ana, "one", model)
