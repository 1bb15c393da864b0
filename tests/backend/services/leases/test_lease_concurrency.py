"""Many annotators asking at once get disjoint samples, on both backends."""

from __future__ import annotations

import threading
from datetime import timedelta

import pytest

from backend.db.base import utcnow
from backend.models.enums import LeaseKind, Role, SampleState
from backend.models.users import User
from backend.services.accounts.users import create_user
from backend.services.captures.seed import seed_samples
from backend.services.leases import queues

N_THREADS = 20


def _make_users(factory, n):
    with factory() as s, s.begin():
        hashed = __import__("backend.services.accounts.security", fromlist=["x"]).hash_password("password-123")
        users = [User(email=f"a{i}@x.org", role=Role.annotator, hashed_password=hashed) for i in range(n)]
        s.add_all(users)
        s.flush()
        return [u.id for u in users]


@pytest.mark.parametrize("samples", [N_THREADS * 2, N_THREADS // 2])
def test_concurrent_next_gives_disjoint_samples(db_url, engine_factory, samples):
    factory = engine_factory(db_url)
    with factory() as s, s.begin():
        ids = set(seed_samples(s, frames=samples, cameras=1))
    user_ids = _make_users(factory, N_THREADS)
    barrier = threading.Barrier(N_THREADS)
    got: dict[int, int | None] = {}
    errors: list[BaseException] = []

    def worker(user_id: int) -> None:
        try:
            with factory() as s:
                user = s.get(User, user_id)
                s.commit()
                barrier.wait()
                with s.begin():
                    lease = queues.acquire(s, user, LeaseKind.annotate, 60)
                got[user_id] = lease.sample_id if lease else None
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(u,)) for u in user_ids]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors, errors
    leased = [v for v in got.values() if v is not None]
    assert len(leased) == len(set(leased)) == min(samples, N_THREADS)
    assert set(leased) <= ids


def test_expired_lease_is_taken_over(db_url, engine_factory):
    factory = engine_factory(db_url)
    with factory() as s, s.begin():
        (sid,) = seed_samples(s, frames=1, cameras=1)
        a = create_user(s, "a@x.org", "password-123", Role.annotator)
        b = create_user(s, "b@x.org", "password-123", Role.annotator)
    with factory() as s, s.begin():
        now = utcnow()
        assert queues.acquire(s, s.get(User, a.id), LeaseKind.annotate, 10, now=now).sample_id == sid
    with factory() as s, s.begin():
        assert queues.acquire(s, s.get(User, b.id), LeaseKind.annotate, 10, now=now + timedelta(seconds=5)) is None
        lease = queues.acquire(s, s.get(User, b.id), LeaseKind.annotate, 10, now=now + timedelta(seconds=11))
        assert lease is not None and lease.sample_id == sid
    with factory() as s:
        sample = queues.load_locked(s, sid)
        assert sample.leased_by_id == b.id and sample.state == SampleState.needs_annotation
