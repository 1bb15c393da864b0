"""Which operating-system process runs a job's attempt, so that a later claimant can tell at once that it
is gone (killed, out of memory) instead of waiting for the job's heartbeat to grow old.

An identity is `<boot id>/<pid namespace>/<pid>/<start time>`, recorded with each claim
(services.jobs.jobs.claim). The boot id and the pid namespace say whether a claimant sees the same process
table as the attempt; the start time (clock ticks after boot, field 22 of /proc/<pid>/stat) tells a
reused pid from the process that claimed. Only Linux offers these; elsewhere no identity is recorded, and
on another machine or in another container nothing can be told: the heartbeat then decides, as before.
"""

from __future__ import annotations

import functools
import logging
import os
from pathlib import Path

logger = logging.getLogger(__name__)

PROC = Path("/proc")


@functools.cache
def _table_of_this_process() -> str | None:
    """`<boot id>/<pid namespace>`: the process table this process sees, or None where there is no /proc."""
    try:
        boot_id = (PROC / "sys/kernel/random/boot_id").read_text().strip()
        namespace = os.readlink(PROC / "self/ns/pid")  # "pid:[4026531836]"
    except OSError:
        return None
    return f"{boot_id}/{namespace.removeprefix('pid:').strip('[]')}"


def _start_time(pid: int) -> tuple[str, int] | None:
    """(state letter, start time in clock ticks after boot) of a process, or None when there is none."""
    try:
        stat = (PROC / str(pid) / "stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2:].split()  # the command name (in parentheses) may hold spaces
    return fields[0], int(fields[19])  # fields 3 (state) and 22 (starttime) of proc(5)


def current() -> str | None:
    """This process's identity (computed per call: a forked pool process has its own), None off Linux."""
    table = _table_of_this_process()
    pid = os.getpid()
    started = _start_time(pid) if table else None
    if table is None or started is None:
        return None
    return f"{table}/{pid}/{started[1]}"


def is_gone(identity: str | None) -> bool:
    """True only when `identity` names a process of the process table this one sees and that process no
    longer runs (exited, killed, a zombie, or its pid taken by another process). False when it runs, and
    whenever this cannot be told (no identity, another machine or container, no /proc)."""
    table = _table_of_this_process()
    if not identity or table is None:
        return False
    parts = identity.rsplit("/", 2)
    if len(parts) != 3 or parts[0] != table:
        return False
    try:
        pid, start = int(parts[1]), int(parts[2])
    except ValueError:
        logger.warning("unreadable worker process identity %r", identity)
        return False
    seen = _start_time(pid)
    return seen is None or seen[0] in ("Z", "X") or seen[1] != start
