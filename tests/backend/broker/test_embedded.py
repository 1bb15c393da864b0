"""The embedded broker's files (broker.embedded): a reader never sees a file half-written, a consumer
claims each message once, and a message that does not parse is set aside instead of killing the worker.

The concurrency tests write from other processes while this one reads, as the API and the worker do. Against
upstream kombu 5.7 / Celery 5.x classes (in-place writes) they fail: about a third of the messages read empty
(JSONDecodeError), exchange tables read empty while created, result files read cut."""

from __future__ import annotations

import logging
import multiprocessing
import os
import shutil
import time
from pathlib import Path
from queue import Empty
from typing import Any

import pytest
from celery import Celery
from kombu import Connection

from backend.broker import claims as broker_claims
from backend.broker import embedded as embedded_broker
from backend.broker.celery_queue import celery_config, embedded_folders, ensure_embedded_folders
from backend.settings import Settings

# fork: the children only touch files and kombu, and need no importable test module (importlib import mode).
FORK = multiprocessing.get_context("fork")
PAYLOAD_CHARS = 20_000  # large enough that a write is not one page


def _options(root: Path) -> dict[str, str]:
    return {"data_folder_in": str(root / "messages"), "data_folder_out": str(root / "messages"),
            "control_folder": str(root / "control")}


def _connection(root: Path) -> Connection:
    (root / "messages").mkdir(parents=True, exist_ok=True)
    return Connection("filesystem://", transport=embedded_broker.Transport, transport_options=_options(root))


def _produce(root: Path, count: int) -> None:
    with _connection(root) as conn:
        queue = conn.SimpleQueue("cpu")
        for i in range(count):
            queue.put({"i": i, "body": "x" * PAYLOAD_CHARS})


def _consume(root: Path, start: Any, taken: Any, count: int, out: Any) -> None:
    """Take messages until the consumers together have taken `count` (a shared counter: a state, not a time
    window); a message taken twice or lost shows in what they return (the deadline only guards a hang)."""
    seen: list[int] = []
    with _connection(root) as conn:
        queue = conn.SimpleQueue("cpu")
        start.wait(30)  # both consumers ready: they start together
        deadline = time.monotonic() + 120
        while taken.value < count and time.monotonic() < deadline:
            try:
                message = queue.get(block=False)
            except Empty:
                continue
            seen.append(message.payload["i"])
            message.ack()
            with taken.get_lock():
                taken.value += 1
    out.put(seen)


def _take_one(conn: Connection, root: Path) -> tuple[Any, Any, Path]:
    """The cpu queue, its first message (not acknowledged) and the file that holds it under claimed/."""
    queue = conn.SimpleQueue("cpu")
    message = queue.get(block=False)
    return queue, message, next(root.glob("claimed/*/*.msg"))


def _take_and_hold(root: Path, taken: Any, killed: Any) -> None:
    """Take one message without acknowledging it, say so, then wait to be killed (`killed` is never set; its
    wait's limit only ends the process should the test die first)."""
    with _connection(root) as conn:
        message = conn.SimpleQueue("cpu").get(block=True, timeout=10)
        taken.put(message.payload["i"])
        killed.wait(60)


def _bind_everywhere(root: Path, queue: str, exchanges: int) -> None:
    with _connection(root) as conn:
        for e in range(exchanges):
            conn.default_channel._queue_bind(f"e{e}", queue, "", queue)


def _write_results(folder: Path, count: int) -> None:
    backend = embedded_broker.ResultBackend(app=Celery(set_as_current=False), url=f"file://{folder}")
    for i in range(count):
        backend.set(b"celery-task-meta-k", str(i % 10).encode() * 4000)  # every value is one digit 4000 times


def test_messages_written_while_a_consumer_polls_arrive_whole_and_in_order(tmp_path):
    count = 1500
    producer = FORK.Process(target=_produce, args=(tmp_path, count))
    received: list[int] = []
    with _connection(tmp_path) as conn:
        queue = conn.SimpleQueue("cpu")
        producer.start()
        deadline = time.monotonic() + 60
        while len(received) < count and time.monotonic() < deadline:
            try:
                message = queue.get(block=False)  # an empty or cut file would raise here
            except Empty:
                continue
            assert len(message.payload["body"]) == PAYLOAD_CHARS
            received.append(message.payload["i"])
            message.ack()
    producer.join(10)
    assert received == list(range(count))  # whole, once each, in sending order
    assert list(tmp_path.glob("rejected/*")) == []
    assert list((tmp_path / "messages").iterdir()) == []  # no temporary file left behind
    assert list((tmp_path / "claimed").iterdir()) == []  # acknowledged: deleted; the closed channel's folder too


def test_two_consumers_claim_each_message_exactly_once(tmp_path):
    count = 600
    _produce(tmp_path, count)
    results, start, taken = FORK.Queue(), FORK.Barrier(2), FORK.Value("i", 0)
    consumers = [FORK.Process(target=_consume, args=(tmp_path, start, taken, count, results)) for _ in range(2)]
    for consumer in consumers:
        consumer.start()
    seen = [results.get(timeout=180) for _ in consumers]
    for consumer in consumers:
        consumer.join(10)
    assert sorted(seen[0] + seen[1]) == list(range(count))
    assert seen[0] and seen[1]  # both consumers took part


def test_a_message_file_that_does_not_parse_is_set_aside_and_the_next_one_delivered(tmp_path, caplog):
    with _connection(tmp_path) as conn:
        queue = conn.SimpleQueue("cpu")
        messages = tmp_path / "messages"
        (messages / "000000000000001_a.cpu.msg").write_bytes(b"")  # an empty file (a writer cut short)
        (messages / "000000000000002_b.cpu.msg").write_bytes(b'{"cut": ')
        (messages / "000000000000003_c.cpu.msg").write_bytes(b"[1, 2]")  # JSON, but no message
        (messages / "000000000000004_d.cpu.msg").write_bytes(b'{"body": "x"}')  # a dict, but no message either
        (messages / "000000000000005_e.gpu.msg").write_bytes(b"")  # another queue's: left alone
        queue.put({"i": 7})
        with caplog.at_level(logging.ERROR, logger=embedded_broker.__name__):
            message = queue.get(block=False)
        assert message.payload == {"i": 7}
        message.ack()
        with pytest.raises(Empty):
            queue.get(block=False)
    rejected = sorted(p.name for p in (tmp_path / "rejected").iterdir())
    assert rejected == [f"00000000000000{i}_{c}.cpu.msg" for i, c in zip("1234", "abcd", strict=True)]
    assert [p.name for p in messages.iterdir()] == ["000000000000005_e.gpu.msg"]
    logged = " ".join(r.getMessage() for r in caplog.records)
    assert "000000000000002_b.cpu.msg is unreadable (JSONDecodeError" in logged and "not a message object" in logged


def test_a_message_whose_properties_are_not_an_object_is_set_aside(tmp_path):
    with _connection(tmp_path) as conn:
        queue = conn.SimpleQueue("cpu")
        (tmp_path / "messages" / "000000000000001_a.cpu.msg").write_bytes(b'{"properties": 5}')
        with pytest.raises(Empty):
            queue.get(block=False)
    assert [p.name for p in (tmp_path / "rejected").iterdir()] == ["000000000000001_a.cpu.msg"]


def test_a_message_taken_by_a_consumer_that_was_killed_is_delivered_again(tmp_path):
    _produce(tmp_path, 2)
    taken, never = FORK.Queue(), FORK.Event()
    holder = FORK.Process(target=_take_and_hold, args=(tmp_path, taken, never))
    holder.start()
    try:
        assert taken.get(timeout=30) == 0
        assert len(list(tmp_path.glob("claimed/*/*.msg"))) == 1  # held on disk, not acknowledged
        with _connection(tmp_path) as conn:
            queue = conn.SimpleQueue("cpu")
            message = queue.get(block=False)
            assert message.payload["i"] == 1  # the live holder's message is not taken from it
            message.ack()
            holder.kill()  # SIGKILL: nothing is acknowledged, nothing restored
            holder.join(10)
            conn.default_channel._next_recovery = 0.0  # the next look recovers (else: recovery_interval_s)
            message = queue.get(block=False)
            assert message.payload["i"] == 0  # delivered again
            message.ack()
            with pytest.raises(Empty):
                queue.get(block=False)
    finally:
        holder.kill()
    assert list((tmp_path / "claimed").iterdir()) == []


def test_unacknowledged_messages_return_to_the_queue_when_a_consumer_closes(tmp_path):
    _produce(tmp_path, 3)
    with _connection(tmp_path) as conn:
        queue = conn.SimpleQueue("cpu")
        queue.get(block=False).ack()
        queue.get(block=False).reject(requeue=True)  # back to the queue at once
        held = queue.get(block=False)
        assert held.payload["i"] == 2 and len(list(tmp_path.glob("claimed/*/*.msg"))) == 1
        assert queue.get(block=False).payload["i"] == 1  # the requeued one
        assert conn.default_channel.basic_get("cpu", no_ack=True) is None  # nothing left to take
    # closed without acknowledging 1 (redelivered) and 2: kombu puts both back, once each
    with _connection(tmp_path) as conn:
        queue = conn.SimpleQueue("cpu")
        again = sorted(queue.get(block=False).payload["i"] for _ in range(2))
        with pytest.raises(Empty):
            queue.get(block=False)
        message = conn.default_channel.basic_get("cpu", no_ack=True)
    assert again == [1, 2] and message is None
    assert list((tmp_path / "claimed").iterdir()) == []


def test_a_dead_consumer_with_this_process_id_is_recovered_too(tmp_path):
    """A restarted worker may get a dead one's pid: owners are told apart by name, not by pid."""
    _produce(tmp_path, 1)
    with _connection(tmp_path) as conn:
        queue, message, held = _take_one(conn, tmp_path)
        dead = tmp_path / "claimed" / f"{os.getpid()}-000000000000"  # as a dead process with our pid left it
        dead.mkdir()
        (tmp_path / "claimed" / f"{dead.name}.lock").touch()
        shutil.copy(held, dead / held.name)
        message.ack()
        assert broker_claims.recover_orphans(tmp_path / "claimed", tmp_path / "messages") == 1
        assert queue.get(block=False).payload["i"] == 0  # delivered again
    assert not dead.exists() and not (tmp_path / "claimed" / f"{dead.name}.lock").exists()


def test_a_forked_child_closing_its_copy_of_a_channel_leaves_the_parents_claims_alone(tmp_path):
    _produce(tmp_path, 1)
    with _connection(tmp_path) as conn:
        _, message, held = _take_one(conn, tmp_path)
        child = FORK.Process(target=conn.default_channel.close)  # as kombu's pools do after a fork
        child.start()
        child.join(10)
        assert child.exitcode == 0
        assert held.exists() and held.parent.with_suffix(".lock").exists()  # still held, still locked
        assert list((tmp_path / "messages").iterdir()) == []  # the child put no copy back
        assert broker_claims.recover_orphans(tmp_path / "claimed", tmp_path / "messages") == 0  # owner alive
        message.ack()
    assert list((tmp_path / "claimed").iterdir()) == []


def test_messages_taken_without_acknowledgement_are_not_held(tmp_path):
    _produce(tmp_path, 1)
    with _connection(tmp_path) as conn:
        message = conn.default_channel.basic_get("cpu", no_ack=True)
        assert message is not None and list(tmp_path.glob("claimed/*/*.msg")) == []


def test_exchange_tables_created_by_several_processes_keep_every_binding_and_always_parse(tmp_path):
    exchanges, queues = 150, ("cpu", "gpu", "celery")
    binders = [FORK.Process(target=_bind_everywhere, args=(tmp_path, q, exchanges)) for q in queues]
    reads = 0
    with _connection(tmp_path) as conn:
        for binder in binders:
            binder.start()
        while any(b.is_alive() for b in binders):
            for e in range(exchanges):
                conn.default_channel.get_table(f"e{e}")  # an empty or cut table would raise here
                reads += 1
        for binder in binders:
            binder.join(10)
        for e in range(exchanges):  # no binding lost when two processes created a table at once
            assert sorted(q.queue for q in conn.default_channel.get_table(f"e{e}")) == sorted(queues)
        conn.default_channel._delete("gpu", "e0", "gpu", "")
        assert sorted(q.queue for q in conn.default_channel.get_table("e0")) == ["celery", "cpu"]
    assert reads > 0


def test_result_files_read_while_rewritten_are_never_cut(tmp_path):
    backend = embedded_broker.ResultBackend(app=Celery(set_as_current=False), url=f"file://{tmp_path}")
    writer = FORK.Process(target=_write_results, args=(tmp_path, 3000))
    writer.start()
    reads = 0
    while writer.is_alive():
        value = backend.get(b"celery-task-meta-k")
        if value is not None:
            assert len(value) == 4000 and value == value[:1] * 4000
            reads += 1
    writer.join(10)
    assert reads > 0


def test_the_embedded_configuration_selects_these_classes(tmp_path):
    settings = Settings(data_dir=tmp_path / "data")
    ensure_embedded_folders(settings)
    app = Celery("t", set_as_current=False)
    app.conf.update(celery_config(settings))
    with app.connection_for_write() as conn:
        assert isinstance(conn.default_channel, embedded_broker.Channel)
        assert conn.default_channel.claimed_folder == embedded_folders(settings)["claimed"]
    assert isinstance(app.backend, embedded_broker.ResultBackend)
    assert app.backend.path.decode() == str(embedded_folders(settings)["results"])


def test_the_redis_configuration_keeps_celery_defaults(tmp_path):
    settings = Settings(data_dir=tmp_path / "data", broker_url="redis://127.0.0.1:6379/0")
    config = celery_config(settings)
    assert config["broker_transport"] is None and config["result_backend"] == "redis://127.0.0.1:6379/0"
