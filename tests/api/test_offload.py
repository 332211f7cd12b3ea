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
