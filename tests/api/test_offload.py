"""Expensive views are built in a child process of their own (at a lower CPU priority), on the same
database, except where the database lives only in this process."""

from __future__ import annotations

import os

import sqlalchemy as sa

from api.services.offload import in_child
from api.store import SqlStore


def _where_built(store: SqlStore, study_id: str) -> bytes:
    with store.session() as session:
        seen = session.scalar(sa.text("SELECT count(*) FROM studies WHERE id = :id"), {"id": study_id})
    return f"{os.getpid()} {os.getpriority(os.PRIO_PROCESS, 0)} {seen}".encode()


def test_a_view_is_built_in_a_niced_child_on_the_same_database(store):
    study_id = store.create_study({"scenario": {}}, owner="alice")

    pid, priority, seen = in_child(_where_built, store, study_id).decode().split()

    assert int(pid) != os.getpid()
    assert int(priority) > os.getpriority(os.PRIO_PROCESS, 0)
    assert seen == "1"


def test_a_database_in_this_process_only_is_read_here():
    from api.db import create_db_engine
    from api.models import Base

    engine = create_db_engine("sqlite://")
    Base.metadata.create_all(engine)  # a schema in this connection's memory: no other process sees it
    store = SqlStore(engine)
    study_id = store.create_study({"scenario": {}}, owner="alice")

    pid, _, seen = in_child(_where_built, store, study_id).decode().split()

    assert int(pid) == os.getpid() and seen == "1"


def test_the_child_ends_when_the_server_is_killed(store, tmp_path):
    import signal
    import subprocess
    import sys
    import time

    study_id = store.create_study({"scenario": {}}, owner="alice")
    script = (
        "import sys\n"
        "from api.db import create_db_engine\n"
        "from api.services.offload import in_child\n"
        "from api.store import SqlStore\n"
        "from tests.api.test_offload import _where_built\n"
        "if __name__ == '__main__':\n"
        "    store = SqlStore(create_db_engine(sys.argv[1]))\n"
        "    print(in_child(_where_built, store, sys.argv[2]).decode().split()[0], flush=True)\n"
        "    sys.stdin.read()\n"  # a server at work until it is killed
    )
    (tmp_path / "server.py").write_text(script)
    url = store.engine.url.render_as_string(hide_password=False)
    server = subprocess.Popen(
        [sys.executable, str(tmp_path / "server.py"), url, study_id], stdin=subprocess.PIPE,
        stdout=subprocess.PIPE, text=True, cwd=os.getcwd(), env={**os.environ, "PYTHONPATH": os.getcwd()},
    )
    try:
        child = int(server.stdout.readline())
        server.send_signal(signal.SIGKILL)
        server.wait(30)
        deadline = time.monotonic() + 60
        while _state(child) != "Z":
            assert time.monotonic() < deadline, "the view-building child outlived its server"
            time.sleep(0.2)
    finally:
        if server.poll() is None:
            server.kill()


def _state(pid: int) -> str:
    """A process's state letter; "Z" also for one that is gone."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "Z"
