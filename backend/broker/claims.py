"""Claims of the embedded broker: where a consumer keeps the messages it was given until they are acknowledged,
and how the messages of a consumer that died go back to the queue (used by broker.embedded).

Layout under the broker's `claimed/` folder, one pair per consumer (a kombu channel that consumed):
- `<pid>-<random>/`: its delivered, unacknowledged message files;
- `<pid>-<random>.lock`: locked (POSIX record lock, `fcntl.lockf`) by the consumer's process while it lives.

Why a POSIX record lock: the kernel releases it when the process ends, however it ends (SIGKILL, out of
memory), and forked children (Celery's prefork pool) do not inherit it, so the lock is free exactly when the
owner process is gone. Such locks never conflict within one process, so a process skips the owners it made
itself (`_OWN_OWNERS`), never by pid (a restarted worker may get a dead one's pid).
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import uuid
from pathlib import Path
from typing import IO

logger = logging.getLogger(__name__)

LOCK_SUFFIX = ".lock"
# Temporary files start with a dot: no reader lists them (not a lock file's owner, not `<stamp>_<uuid>.<queue>.msg`
# of the transport, not a result key's `celery-task-meta-` prefix).
TEMP_PREFIX = ".tmp-"
_OWN_OWNERS: set[str] = set()  # owners created by this process
os.register_at_fork(after_in_child=_OWN_OWNERS.clear)  # a child owns none of its parent's


class Claims:
    """One consumer's claims folder and its liveness lock (module docstring). Raises OSError when the folder
    cannot be made."""

    def __init__(self, claimed_folder: Path) -> None:
        self.owner = f"{os.getpid()}-{uuid.uuid4().hex[:12]}"
        self._pid = os.getpid()
        self.lock_path = claimed_folder / f"{self.owner}{LOCK_SUFFIX}"
        self.folder = claimed_folder / self.owner
        # Locked before it gets its name: a recoverer never sees this owner's lock file unlocked.
        temp = claimed_folder / f"{TEMP_PREFIX}{self.owner}{LOCK_SUFFIX}"
        self._lock: IO[bytes] | None = open(temp, "a+b")  # noqa: SIM115  (held open while the consumer lives)
        try:
            fcntl.lockf(self._lock.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            _OWN_OWNERS.add(self.owner)
            os.replace(temp, self.lock_path)
            self.folder.mkdir()
        except BaseException:
            self._lock.close()
            temp.unlink(missing_ok=True)
            raise

    def take(self, message_file: Path) -> Path | None:
        """Move a queued message file into this folder (atomic: of several consumers, one wins); returns
        where it now is, or None when another consumer took it first."""
        held = self.folder / message_file.name
        try:
            os.rename(message_file, held)
        except FileNotFoundError:
            if not self.folder.is_dir():  # someone removed it: make it again, and say so
                self.folder.mkdir(parents=True, exist_ok=True)
                logger.warning("the broker claims folder %s had vanished; made again", self.folder)
            return None
        return held

    def close(self) -> None:
        """Give the lock up; the folder and lock file go too when empty (else a later recovery takes what is
        left). In a forked child, only the inherited file is closed: the claims are the parent's."""
        if self._lock is None:
            return
        if os.getpid() == self._pid:
            with contextlib.suppress(OSError):
                self.folder.rmdir()  # only if empty
                self.lock_path.unlink(missing_ok=True)
        self._lock.close()
        self._lock = None


def recover_orphans(claimed_folder: Path, queue_folder: Path) -> int:
    """Put the messages held by consumers whose process has ended back into `queue_folder` under their old
    names (so at the queue's front); returns how many. Safe to run from several processes at once."""
    returned = 0
    for lock_path in sorted(claimed_folder.glob(f"*{LOCK_SUFFIX}")):
        owner = lock_path.name.removesuffix(LOCK_SUFFIX)
        if owner in _OWN_OWNERS or owner.startswith(TEMP_PREFIX):
            continue
        try:
            fd = os.open(lock_path, os.O_RDWR)
        except FileNotFoundError:
            continue  # recovered by another consumer meanwhile
        try:
            try:
                fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                continue  # its process lives
            folder = claimed_folder / owner
            for held in sorted(folder.glob("*.msg")) if folder.is_dir() else []:
                with contextlib.suppress(FileNotFoundError):  # another recoverer's
                    os.rename(held, queue_folder / held.name)
                    returned += 1
            try:
                folder.rmdir()
            except FileNotFoundError:
                pass
            except OSError:
                continue  # not emptied: the lock file stays, for the next recovery
            lock_path.unlink(missing_ok=True)
        finally:
            os.close(fd)
    if returned:
        logger.warning("%d broker message(s) delivered to a consumer that ended without acknowledging them went "
                       "back to the queue", returned)
    return returned
