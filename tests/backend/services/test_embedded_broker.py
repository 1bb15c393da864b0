"""The embedded broker's files (services.embedded_broker): a reader never sees a file half-written, a consumer
claims each message once, and a message that does not parse is set aside instead of killing the worker.

The concurrency tests write from other processes while this one reads, as the API and the worker do. Against
upstream kombu 5.7 / Celery 5.x classes (in-place writes) they fail: about a third of the messages read empty
(JSONDecodeError), exchange tables read empty while created, result files read cut."""

from __future__ import annotations

import logging
import multiprocessing
import time
from pathlib import Path
from queue import Empty
from typing import Any

import pytest
from celery import Celery
from kombu import Connection

from backend.services import embedded_broker
from backend.services.celery_queue import celery_config, embedded_folders, ensure_embedded_folders
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
        for i in range(count):
            conn.default_channel._put("cpu", {"i": i, "body": "x" * PAYLOAD_CHARS})


def _consume(root: Path, until: float, out: Any) -> None:
    seen: list[int] = []
    with _connection(root) as conn:
        while time.monotonic() < until:
            try:
                seen.append(conn.default_channel._get("cpu")["i"])
            except Empty:
                time.sleep(0.001)
    out.put(seen)


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
        producer.start()
        deadline = time.monotonic() + 60
        while len(received) < count and time.monotonic() < deadline:
            try:
                message = conn.default_channel._get("cpu")  # an empty or cut file would raise here
            except Empty:
                continue
            assert len(message["body"]) == PAYLOAD_CHARS
            received.append(message["i"])
    producer.join(10)
    assert received == list(range(count))  # whole, once each, in sending order
    assert list(tmp_path.glob("rejected/*")) == []
    assert [p.name for p in (tmp_path / "messages").iterdir()] == []  # no temporary file left behind


def test_two_consumers_claim_each_message_exactly_once(tmp_path):
    count = 600
    _produce(tmp_path, count)
    results = FORK.Queue()
    consumers = [FORK.Process(target=_consume, args=(tmp_path, time.monotonic() + 8, results)) for _ in range(2)]
    for consumer in consumers:
        consumer.start()
    seen = [results.get(timeout=30) for _ in consumers]
    for consumer in consumers:
        consumer.join(10)
    assert sorted(seen[0] + seen[1]) == list(range(count))
    assert seen[0] and seen[1]  # both consumers took part


def test_a_message_file_that_does_not_parse_is_set_aside_and_the_next_one_delivered(tmp_path, caplog):
    with _connection(tmp_path) as conn:
        messages = tmp_path / "messages"
        (messages / "000000000000001_a.cpu.msg").write_bytes(b"")  # an empty file (a writer cut short)
        (messages / "000000000000002_b.cpu.msg").write_bytes(b'{"cut": ')
        (messages / "000000000000003_c.cpu.msg").write_bytes(b"[1, 2]")  # JSON, but no message
        (messages / "000000000000004_d.gpu.msg").write_bytes(b"")  # another queue's: left alone
        conn.default_channel._put("cpu", {"i": 7})
        with caplog.at_level(logging.ERROR, logger=embedded_broker.__name__):
            assert conn.default_channel._get("cpu") == {"i": 7}
        with pytest.raises(Empty):
            conn.default_channel._get("cpu")
    rejected = sorted(p.name for p in (tmp_path / "rejected").iterdir())
    assert rejected == ["000000000000001_a.cpu.msg", "000000000000002_b.cpu.msg", "000000000000003_c.cpu.msg"]
    assert [p.name for p in messages.iterdir()] == ["000000000000004_d.gpu.msg"]
    logged = " ".join(r.getMessage() for r in caplog.records)
    assert "000000000000002_b.cpu.msg is unreadable (JSONDecodeError" in logged and "not a message object" in logged


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
