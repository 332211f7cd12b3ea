"""Study leases in the database: which process drives a study, ``demcal serve`` or
``demcal calibrate``, whether Redis is used or not.

The rule: a study is advanced only by the process holding its lease (``studies.driver`` until
``studies.driver_until``). The holder renews it while it drives (every tick of ``serve``, every
step of ``calibrate``) and releases it when the study ends or the process stops. A holder that
dies stops renewing; after ``DEMCAL_LEASE_TTL_S`` the lease has expired and the first process
that asks takes the study over: any ``serve`` replica at its next scan, or
``demcal calibrate --resume``. While the lease is live, ``calibrate --resume`` refuses (exit 2,
naming the holder) and ``serve`` leaves the study alone.

Every operation is one conditional UPDATE, so two processes racing for a lease are decided by
the database: exactly one row count is 1. Times are the processes' own UTC clocks (kept in step
by NTP on any real deployment; the TTL dwarfs their skew).
"""

from __future__ import annotations

import os
import socket
import uuid
from datetime import datetime, timedelta

import sqlalchemy as sa

from api.models import StudyRow, utcnow
from api.store.base import KEEP_VERSION  # a lease is no change of the study

LEASE_TTL_S = 30.0


def owner_id() -> str:
    """This process, as lease holders are named: readable, unique per start."""
    return f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"


class DatabaseLeases:
    """acquire / renew / release / holder of study leases for one owner (see the module doc)."""

    def __init__(self, store, owner: str | None = None, ttl_s: float = LEASE_TTL_S) -> None:
        self._store = store
        self.owner = owner or owner_id()
        self._ttl = timedelta(seconds=ttl_s)
        # Renewing three times per TTL leaves two missed renewals before another process may
        # take the study.
        self.renew_every_s = ttl_s / 3

    def _take(self, study_id: str, *condition) -> bool:
        now = utcnow()
        with self._store.session() as s:
            return bool(
                s.execute(
                    sa.update(StudyRow)
                    .where(StudyRow.id == study_id, *condition)
                    .values(driver=self.owner, driver_until=now + self._ttl, **KEEP_VERSION)
                    .execution_options(synchronize_session=False)
                ).rowcount
            )

    def acquire(self, study_id: str) -> bool:
        """Take the lease if nobody holds it, it expired, or we hold it already."""
        free = sa.or_(
            StudyRow.driver.is_(None), StudyRow.driver_until < utcnow(), StudyRow.driver == self.owner
        )
        return self._take(study_id, free)

    def renew(self, study_id: str) -> bool:
        """Extend a lease we hold, or take it back if it is free (it expired while we were slow
        and nobody took it); False if another process holds it now."""
        return self.acquire(study_id)

    def release(self, study_id: str) -> None:
        with self._store.session() as s:
            s.execute(
                sa.update(StudyRow)
                .where(StudyRow.id == study_id, StudyRow.driver == self.owner)
                .values(driver=None, driver_until=None, **KEEP_VERSION)
                .execution_options(synchronize_session=False)
            )

    def holder(self, study_id: str) -> tuple[str, datetime] | None:
        """(owner, expiry) of a live lease on the study, or None."""
        with self._store.session() as s:
            row = s.execute(
                sa.select(StudyRow.driver, StudyRow.driver_until).where(StudyRow.id == study_id)
            ).one_or_none()
        if row is None or row.driver is None or row.driver_until is None or row.driver_until < utcnow():
            return None
        return row.driver, row.driver_until
