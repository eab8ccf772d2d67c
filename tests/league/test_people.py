"""People: roles checked on every call, invites that work once, hashed tokens, throttled logins, CSRF tokens."""

from __future__ import annotations

import threading
import time
from datetime import timedelta

import pytest
from sqlalchemy import select

from racerlab.league import LeagueError, people
from racerlab.league.tables import Invite, Token, User
from tests.league.conftest import PASSWORD, racer


def test_an_invite_works_once_and_the_password_is_argon2id(league, admin):
    inv = league.invite(admin, "ana")
    ana = league.accept_invite(inv.code, PASSWORD)
    assert (ana.alias, ana.role) == ("ana", "racer")
    with pytest.raises(LeagueError, match="unknown, used or expired") as err:
        league.accept_invite(inv.code, PASSWORD)
    assert err.value.status == 404
    with league.store.read() as s:
        stored = s.scalars(select(User).where(User.alias == "ana")).one().password_hash
        codes = [i.code_hash for i in s.scalars(select(Invite))]
    assert stored.startswith("$argon2id$") and PASSWORD not in stored
    assert codes == [people.digest(inv.code)] and inv.code not in codes
    assert league.authenticate("ana", PASSWORD) == ana


def test_an_expired_invite_is_refused(league, admin):
    inv = league.invite(admin, "bob", ttl=timedelta(seconds=-1))
    with pytest.raises(LeagueError, match="expired"):
        league.accept_invite(inv.code, PASSWORD)


def test_roles_decide_who_may_do_what(league, admin):
    ana = racer(league, admin, "ana")
    fac = racer(league, admin, "fay", "facilitator")
    with pytest.raises(LeagueError, match="may not invite racer") as err:
        league.invite(ana, "cyd")
    assert err.value.status == 403
    league.invite(fac, "cyd")  # a facilitator invites racers ...
    with pytest.raises(LeagueError, match="may not invite staff"):
        league.invite(fac, "dee", "admin")  # ... but not staff
    with pytest.raises(LeagueError, match="may not audit view"):
        league.audit(ana)
    assert league.audit(fac)


def test_a_disabled_account_stops_at_once_even_with_its_actor(league, admin):
    ana = racer(league, admin, "ana")
    token = league.issue_token(ana).token
    league.set_user(admin, "ana", active=False)
    with pytest.raises(LeagueError, match="disabled") as err:
        league.races(ana)
    assert err.value.status == 401
    with pytest.raises(LeagueError, match="disabled"):
        league.actor_for_token(token)
    with pytest.raises(LeagueError, match="wrong alias or password"):
        league.authenticate("ana", PASSWORD)


def test_tokens_are_stored_hashed_expire_and_revoke(league, admin):
    issued = league.issue_token(admin, "api", label="laptop")
    assert league.actor_for_token(issued.token) == admin
    with league.store.read() as s:
        hashes = [t.token_hash for t in s.scalars(select(Token))]
    assert issued.token not in hashes and people.digest(issued.token) in hashes
    session = league.issue_token(admin, "session")
    with pytest.raises(LeagueError, match="not logged in"):
        league.actor_for_token(session.token, "api")  # a session token is no API token
    assert league.actor_for_token(session.token, "session") == admin
    league.end_session(session.token)
    with pytest.raises(LeagueError, match="revoked or expired"):
        league.actor_for_token(session.token, "session")
    old = league.issue_token(admin, "api", ttl=timedelta(seconds=-1))
    with pytest.raises(LeagueError, match="revoked or expired"):
        league.actor_for_token(old.token)
    league.revoke_token(admin, issued.id)
    with pytest.raises(LeagueError, match="revoked or expired") as err:
        league.actor_for_token(issued.token)
    assert err.value.status == 401


def test_failed_logins_are_throttled_per_alias_and_per_client(league, admin):
    for _ in range(people.THROTTLE):
        with pytest.raises(LeagueError, match="wrong alias or password"):
            league.authenticate("admin", "not the password", client="10.0.0.1")
    with pytest.raises(LeagueError, match="too many failed logins") as err:
        league.authenticate("admin", PASSWORD, client="10.0.0.2")  # the right password, but the alias is throttled
    assert err.value.status == 429
    with pytest.raises(LeagueError, match="wrong alias"):  # an unknown alias is answered like a wrong password
        league.authenticate("nobody", PASSWORD)


def test_open_sign_up_is_off_until_an_admin_turns_it_on(league, admin):
    with pytest.raises(LeagueError, match="invite only"):
        league.sign_up("walkup", PASSWORD)
    league.set_open_signup(admin, True)
    assert league.sign_up("walkup", PASSWORD).role == "racer"
    with pytest.raises(LeagueError, match="taken"):
        league.sign_up("walkup", PASSWORD)


@pytest.mark.parametrize("alias", ["ab", "x" * 21, "a b", "<script>", "ana;--"])
def test_aliases_follow_droas_rule(league, admin, alias):
    with pytest.raises(LeagueError, match="3-20 letters"):
        league.invite(admin, alias)


def test_a_short_password_is_refused(league, admin):
    inv = league.invite(admin, "ana")
    with pytest.raises(LeagueError, match=f"at least {people.MIN_PASSWORD} characters"):
        league.accept_invite(inv.code, "short")


def test_csrf_tokens_are_bound_to_the_session_and_the_store(league, admin):
    secret = league.secret()
    a, b = league.issue_token(admin, "session").token, league.issue_token(admin, "session").token
    tok = people.csrf_token(secret, a)
    assert people.csrf_ok(secret, a, tok)
    assert not people.csrf_ok(secret, b, tok) and not people.csrf_ok(secret, a, None)
    assert not people.csrf_ok("another store's secret", a, tok)


class _SlowHasher:
    """Counts how many password checks run at once (argon2's own checks take the CPU and cannot be counted)."""

    def __init__(self):
        self.now = self.most = 0
        self.lock = threading.Lock()

    def verify(self, stored, password):
        with self.lock:
            self.now += 1
            self.most = max(self.most, self.now)
        time.sleep(0.05)
        with self.lock:
            self.now -= 1
        return True


def test_a_crowd_logging_in_at_once_hashes_a_few_passwords_at_a_time(monkeypatch):
    counting = _SlowHasher()
    monkeypatch.setattr(people, "_hasher", counting)
    threads = [threading.Thread(target=people.verify_password, args=("stored", "a password")) for _ in range(12)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert counting.most == people.HASHES_AT_ONCE and people.HASHES_AT_ONCE >= 1


def test_a_token_lookup_writes_its_last_use_once_a_minute(league, admin):
    from racerlab.league.tables import utcnow

    issued = league.issue_token(admin, "api", "script")
    league.actor_for_token(issued.token)
    with league.store.read() as s:
        first = s.scalars(select(Token).where(Token.token_hash == people.digest(issued.token))).one().last_used_at
    league.actor_for_token(issued.token)
    with league.store.read() as s:
        row = s.scalars(select(Token).where(Token.token_hash == people.digest(issued.token))).one()
    assert first is not None and row.last_used_at == first  # a second lookup within the minute reads only
    with league.store.write() as s:
        s.get(Token, row.id).last_used_at = utcnow() - timedelta(minutes=2)
    assert league.actor_for_token(issued.token) == admin
    with league.store.read() as s:
        assert utcnow() - s.get(Token, row.id).last_used_at < timedelta(seconds=30)
