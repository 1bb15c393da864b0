"""The embedded broker: kombu's filesystem transport and Celery's file result backend, made safe for readers
that poll while writers write.

Why our own subclasses: upstream (kombu 5.x `kombu.transport.filesystem`, `celery.backends.filesystem`) writes
each file in place: open (create, truncate), then write. A process polling the folder can open the file in
between and read it empty or cut. In the worker that is a `JSONDecodeError` in the consumer loop, which Celery
treats as unrecoverable: the embedded worker died mid-test in CI this way, and it could in the demo. The same
holds for the exchange tables (created, then locked) and the result files chords poll.
tests/backend/broker/test_embedded.py reproduces all three against upstream.

Here:
- every file is written under a temporary name that no reader lists, then renamed into place (atomic within a
  filesystem), so a reader sees a whole file or none (`write_whole`);
- a consumer claims a message by renaming it into its own folder under `claimed/`, on the same filesystem
  (upstream moves it to the system temp folder: a copy when that is another filesystem, which two consumers
  can both make), and deletes it only once the message is acknowledged: Celery's `acks_late` then means
  what it means on Redis. The messages of a consumer whose process died (killed, out of memory) go back to
  the queue when another consumer next looks (every `recovery_interval_s`, and at its start;
  broker.claims); upstream keeps unacknowledged messages in memory only, and a crash loses them;
- a message file that does not parse all the same (another program's, a disk fault) is moved to `rejected/`
  with an error in the log, and the consumer goes on with the next one;
- writers of an exchange table take an exclusive lock on a lock file of their own, never on the table itself
  (a replaced file's lock would protect nothing); readers need no lock.
"""

from __future__ import annotations

import contextlib
import fcntl
import itertools
import logging
import os
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from queue import Empty
from time import monotonic, monotonic_ns
from typing import Any

from celery.backends.filesystem import FilesystemBackend
from kombu.exceptions import ChannelError
from kombu.transport import filesystem, virtual
from kombu.utils.encoding import bytes_to_str, str_to_bytes
from kombu.utils.json import dumps, loads
from kombu.utils.objects import cached_property

from backend.broker.claims import TEMP_PREFIX, Claims, recover_orphans

logger = logging.getLogger(__name__)

_SEQUENCE = itertools.count()


def write_whole(path: Path, data: bytes) -> None:
    """Write `data` to `path` so that a concurrent reader sees either no file or all of it.

    The bytes go to a temporary file in the same folder, which `os.replace` then renames onto `path`.
    Raises OSError (nothing left behind) when the folder cannot be written.
    """
    temp = path.with_name(f"{TEMP_PREFIX}{uuid.uuid4().hex}-{path.name}")
    try:
        with open(temp, "wb") as f:
            f.write(data)
        os.replace(temp, path)
    except BaseException:
        temp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def exclusive_lock(path: Path) -> Iterator[None]:
    """Hold an exclusive advisory lock (flock) on the file `path`, created if absent, for the block."""
    with open(path, "a+b") as f:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f.fileno(), fcntl.LOCK_UN)


class Channel(filesystem.Channel):
    """kombu's filesystem channel with whole-file writes and claims held until acknowledged (module docstring).

    Transport options, besides upstream's `data_folder_in`, `data_folder_out` and `control_folder`:
    `claimed_folder` and `rejected_folder` (default: `claimed` and `rejected` beside `data_folder_in`) and
    `recovery_interval_s` (default 5). Upstream's `store_processed` is not supported: an acknowledged message
    is deleted.
    """

    def __init__(self, connection: Any, **kwargs: Any) -> None:
        self._held: dict[str, Path] = {}  # delivery tag -> its file in this channel's claims folder
        self._claims: Claims | None = None  # made when this channel first consumes (publishers never do)
        self._next_recovery = 0.0
        self._pid = os.getpid()
        super().__init__(connection, **kwargs)

    # -- messages ------------------------------------------------------------------------------------
    def _put(self, queue: str, payload: dict[str, Any], **kwargs: Any) -> None:
        # Names sort in sending order: a zero-padded nanosecond stamp, then this process's sequence number for
        # equal stamps (upstream's unpadded milliseconds, then a random uuid, misorder within a millisecond).
        name = f"{monotonic_ns():020d}_{next(_SEQUENCE):012d}_{uuid.uuid4().hex}.{queue}.msg"
        try:
            write_whole(Path(self.data_folder_out) / name, str_to_bytes(dumps(payload)))
        except OSError as exc:
            raise ChannelError(f"cannot add message {name!r} to the broker folder {self.data_folder_out}") from exc

    def _get(self, queue: str) -> dict[str, Any]:
        wanted = f"{queue}.msg"
        folder = Path(self.data_folder_in)
        try:
            claims = self._consumer_claims()
            if monotonic() >= self._next_recovery:
                self._next_recovery = monotonic() + self.recovery_interval_s
                recover_orphans(self.claimed_folder, folder)
            names = sorted(os.listdir(folder))
        except OSError as exc:  # a ChannelError: Celery's consumer reconnects instead of dying
            raise ChannelError(f"the embedded broker's folders under {folder.parent} failed: {exc}") from exc
        for name in names:
            if name.partition(".")[2] != wanted:
                continue
            try:
                held = claims.take(folder / name)
            except OSError as exc:
                raise ChannelError(f"cannot claim broker message {name!r} from {folder}: {exc}") from exc
            if held is None:
                continue  # another consumer took it
            try:
                message = loads(bytes_to_str(held.read_bytes()))
            except (OSError, ValueError, TypeError) as exc:  # ValueError: JSONDecodeError, UnicodeDecodeError
                self._reject(held, f"unreadable ({exc.__class__.__name__}: {exc})")
                continue
            tag = _delivery_tag(message)
            if not isinstance(tag, str):
                self._reject(held, "not a message object (no properties.delivery_tag)")
                continue
            self._held[tag] = held  # deleted when acknowledged, rejected or restored
            return message
        raise Empty()

    def _consumer_claims(self) -> Claims:
        if self._claims is None:
            self._claims = Claims(self.claimed_folder)
        return self._claims

    def _reject(self, held: Path, why: str) -> None:
        target = self.rejected_folder / held.name
        try:
            os.replace(held, target)
        except OSError:
            target = held  # left where it is; still out of the queue
        logger.error("broker message %s is %s; moved to %s, the worker goes on", held.name, why, target)

    # -- acknowledgement: a delivered message stays on disk until then -------------------------------
    def basic_get(self, queue: str, no_ack: bool = False, **kwargs: Any) -> Any:
        message = super().basic_get(queue, no_ack=no_ack, **kwargs)
        if message is not None and no_ack:
            self._release(message.delivery_tag)
        return message

    def basic_consume(self, queue: str, no_ack: bool, callback: Any, consumer_tag: str, **kwargs: Any) -> Any:
        if no_ack:  # e.g. Celery's remote-control (pidbox) queues: nothing will acknowledge these
            deliver = callback

            def callback(message: Any) -> Any:
                self._release(message.delivery_tag)
                return deliver(message)

        return super().basic_consume(queue, no_ack, callback, consumer_tag, **kwargs)

    def basic_ack(self, delivery_tag: str, multiple: bool = False) -> None:
        super().basic_ack(delivery_tag, multiple=multiple)
        self._release(delivery_tag)

    def basic_reject(self, delivery_tag: str, requeue: bool = False) -> None:
        super().basic_reject(delivery_tag, requeue=requeue)
        if not requeue:  # requeued: _restore released it (after putting the copy back, which may be taken
            self._release(delivery_tag)  # and held under the same tag at once)

    def _restore(self, message: Any) -> None:
        # Unhold before the copy goes back: the copy keeps the delivery tag, and this channel may take it
        # and hold it again at once (an ack or reject may come from another thread than the consumer's).
        held = self._unhold(message.delivery_tag)
        try:
            super()._restore(message)
        except BaseException:
            if held is not None:
                self._held[message.delivery_tag] = held  # still held: a later restore or recovery takes it
            raise
        if held is not None:
            held.unlink(missing_ok=True)

    def _release(self, delivery_tag: str) -> None:
        held = self._unhold(delivery_tag)
        if held is not None:
            held.unlink(missing_ok=True)

    def _unhold(self, delivery_tag: str) -> Path | None:
        # kombu may settle a message on another channel of the connection than the one that took it
        # (Transport._reject_inbound_message uses the first channel): look in all of ours.
        for channel in [self, *(c for c in getattr(self.connection, "channels", ()) if c is not self)]:
            held = getattr(channel, "_held", {}).pop(delivery_tag, None)
            if held is not None:
                return held
        return None

    def close(self) -> None:
        if os.getpid() != self._pid:
            self.do_restore = False  # a forked child's copy: the unacknowledged messages are the parent's
        super().close()  # puts unacknowledged messages back (kombu's restore at shutdown)
        if self._claims is not None:
            self._claims.close()
            self._claims = None

    # -- exchange tables -----------------------------------------------------------------------------
    def get_table(self, exchange: str) -> list[filesystem.exchange_queue_t]:
        file = self._exchange_file(exchange)
        try:
            return [filesystem.exchange_queue_t(*q) for q in loads(bytes_to_str(file.read_bytes()))]
        except FileNotFoundError:
            return []
        except OSError as exc:
            raise ChannelError(f"cannot read the exchange table {file}") from exc

    def _queue_bind(self, exchange: str, routing_key: str, pattern: str, queue: str) -> None:
        binding = filesystem.exchange_queue_t(routing_key or "", pattern or "", queue or "")
        self._update_table(exchange, lambda table: table if binding in table else [binding, *table])

    def _delete(self, queue: str, exchange: str, routing_key: str, pattern: str, *args: Any, **kwargs: Any) -> None:
        # The virtual channel's bookkeeping, not upstream filesystem's (which rewrites the table in place).
        virtual.Channel._delete(self, queue, exchange, routing_key, pattern, *args, **kwargs)
        binding = filesystem.exchange_queue_t(routing_key or "", pattern or "", queue or "")
        self._update_table(exchange, lambda table: [q for q in table if q != binding])

    def _update_table(self, exchange: str, change: Callable[[list[Any]], list[Any]]) -> None:
        file = self._exchange_file(exchange)
        self.control_folder.mkdir(parents=True, exist_ok=True)
        try:
            with exclusive_lock(file.with_name(f"{file.name}.lock")):
                table = self.get_table(exchange)
                changed = change(table)
                if changed != table:
                    write_whole(file, str_to_bytes(dumps(changed)))
        except OSError as exc:
            raise ChannelError(f"cannot update the exchange table {file}") from exc

    # -- folders -------------------------------------------------------------------------------------
    @cached_property
    def recovery_interval_s(self) -> float:
        return float(self.transport_options.get("recovery_interval_s", 5.0))

    @cached_property
    def claimed_folder(self) -> Path:
        return self._folder("claimed_folder", "claimed")

    @cached_property
    def rejected_folder(self) -> Path:
        return self._folder("rejected_folder", "rejected")

    def _folder(self, option: str, default: str) -> Path:
        folder = Path(self.transport_options.get(option) or Path(self.data_folder_in).parent / default)
        folder.mkdir(parents=True, exist_ok=True)
        return folder


def _delivery_tag(message: Any) -> Any:
    """`message["properties"]["delivery_tag"]`, or None where a decoded file does not have that shape."""
    properties = message.get("properties") if isinstance(message, dict) else None
    return properties.get("delivery_tag") if isinstance(properties, dict) else None


class Transport(filesystem.Transport):
    """kombu's filesystem transport on `Channel` above; select it with Celery's `broker_transport` setting."""

    Channel = Channel

    def __init__(self, client: Any, **kwargs: Any) -> None:
        super().__init__(client, **kwargs)
        # Upstream shares one in-memory record of declared exchanges and bindings per process, so a second
        # broker folder in the same process (tests, benchmarks) never got its exchange tables written. The
        # tables on disk are the state; each connection declares what it uses (idempotent).
        self.state = virtual.BrokerState()


class ResultBackend(FilesystemBackend):
    """Celery's file result backend with whole-file writes (chords poll these files while tasks write them).

    Select it with `result_backend = "backend.broker.embedded:ResultBackend+file:///abs/folder"`.
    """

    def set(self, key: bytes, value: Any) -> None:
        write_whole(Path(os.fsdecode(self._filename(key))), value if isinstance(value, bytes) else str_to_bytes(value))


TRANSPORT = f"{__name__}:Transport"
RESULT_BACKEND = f"{__name__}:ResultBackend"
