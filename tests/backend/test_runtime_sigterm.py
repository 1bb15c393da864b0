"""A process that started a stack (`backend.runtime.start_stack`) and is then terminated (`kill`, a CI timeout)
stops the API and worker it started: they run in sessions of their own, so nothing else would."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

HOLDER = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from backend.db.migrate import upgrade
    from backend.runtime import start_stack
    from backend.settings import Settings

    data = Path(sys.argv[1])
    settings = Settings(data_dir=data, database_url=f"sqlite:///{data / 'db.sqlite3'}", environment="test",
                        secret_key="x" * 40)
    data.mkdir(parents=True, exist_ok=True)
    upgrade(settings.resolved_database_url)
    stack = start_stack(settings, start_worker=False)
    try:
        print(stack.api.pid, flush=True)
        time.sleep(600)
    finally:
        stack.stop()
        print("stopped", flush=True)
""")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_sigterm_to_the_holder_stops_the_stack_it_started(tmp_path: Path):
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(tmp_path / "data")], stdout=subprocess.PIPE,
                              text=True, env=env)
    api_pid = None
    try:
        api_pid = int(holder.stdout.readline())  # blocks until the API answered its health check
        assert _alive(api_pid)
        holder.send_signal(signal.SIGTERM)
        out, _ = holder.communicate(timeout=120)
        assert holder.returncode == 128 + signal.SIGTERM
        assert "stopped" in out
        assert not _alive(api_pid), "the API outlived the process that started it"
    finally:
        if holder.poll() is None:
            holder.kill()
        if api_pid is not None and _alive(api_pid):
            os.kill(api_pid, signal.SIGKILL)  # what a failing run would otherwise leave behind
