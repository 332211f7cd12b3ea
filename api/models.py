"""The store's tables (SQLAlchemy 2 declarative models), and nothing else.

These classes are the rows. They are never sent on the wire (``api/schemas.py`` holds the wire
models) and carry no business rules (``api/store/`` and ``api/services/`` do). Every change here
needs an Alembic migration in ``migrations/versions/``: the server refuses to start on a schema
that is not at the head revision.

Portability notes: timestamps are stored as UTC and read back timezone-aware on SQLite too;
objective values that may be infinite are stored as a value plus a kind column (optuna's
``TrialValueModel`` does the same), because neither JSON nor every SQL driver round-trips inf.
"""

from __future__ import annotations

import math
from datetime import UTC, datetime
from enum import StrEnum
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship

NAMING_CONVENTION = {
    "ix": "ix_%(table_name)s_%(column_0_N_name)s",
    "uq": "uq_%(table_name)s_%(column_0_N_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}


def utcnow() -> datetime:
    return datetime.now(UTC)


class UTCDateTime(sa.TypeDecorator):
    """A timestamp that always comes back timezone-aware UTC (SQLite drops the zone otherwise)."""

    impl = sa.DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            value = value.replace(tzinfo=UTC)
        value = value.astimezone(UTC)
        # SQLite compares timestamps as text, so store them without an offset suffix.
        return value.replace(tzinfo=None) if dialect.name == "sqlite" else value

    def process_result_value(self, value: datetime | None, dialect) -> datetime | None:
        if value is None:
            return None
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


class ValueKind(StrEnum):
    """How an objective value is stored: finite in the value column, or one of the specials."""

    FINITE = "finite"
    INF = "inf"
    NEG_INF = "-inf"
    NAN = "nan"


def encode_value(value: float | None) -> tuple[float | None, str | None]:
    """(value column, kind column) for an objective value."""
    if value is None:
        return None, None
    if math.isnan(value):
        return None, ValueKind.NAN.value
    if math.isinf(value):
        return None, (ValueKind.INF if value > 0 else ValueKind.NEG_INF).value
    return float(value), ValueKind.FINITE.value


def decode_value(value: float | None, kind: str | None) -> float | None:
    """The objective value back from its two columns."""
    if kind is None:
        return None
    return {
        ValueKind.FINITE: value,
        ValueKind.INF: math.inf,
        ValueKind.NEG_INF: -math.inf,
        ValueKind.NAN: math.nan,
    }[ValueKind(kind)]


class Base(DeclarativeBase):
    metadata = sa.MetaData(naming_convention=NAMING_CONVENTION)
    type_annotation_map = {datetime: UTCDateTime(), dict[str, Any]: sa.JSON(), bytes: sa.LargeBinary()}


class StudyRow(Base):
    """A calibration study: its definition (StudyDefinition as JSON), status and GA state."""

    __tablename__ = "studies"

    id: Mapped[str] = mapped_column(sa.String(64), primary_key=True)
    name: Mapped[str] = mapped_column(sa.String(200), default="")
    owner: Mapped[str | None] = mapped_column(sa.String(100), index=True)
    status: Mapped[str] = mapped_column(sa.String(16), index=True)
    definition: Mapped[dict[str, Any]]
    generation: Mapped[int] = mapped_column(default=0)
    ga_state: Mapped[bytes | None] = mapped_column(deferred=True)
    recommendation: Mapped[dict[str, Any] | None]
    message: Mapped[str] = mapped_column(sa.Text, default="")
    extra: Mapped[dict[str, Any]] = mapped_column(default=dict)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)
    # Set by the store on the first move to running and on the move to done, cancelled or failed.
    started_at: Mapped[datetime | None]
    finished_at: Mapped[datetime | None]
    # The lease of the process driving the study (``api/store/leases.py``): who, and until when.
    driver: Mapped[str | None] = mapped_column(sa.String(200))
    driver_until: Mapped[datetime | None]
    # The study's change counter: every write to its trials (``StoreBase._change_numbers``) and
    # to this row (the onupdate below, unless a write keeps the version: ``KEEP_VERSION``) takes
    # the next number, in commit order (the row stays locked until the commit).
    trial_changes: Mapped[int] = mapped_column(
        sa.BigInteger, default=0, server_default="0", onupdate=sa.text("trial_changes + 1")
    )
    # The number of this row's own last change (status, generation, ranking, new trials): the
    # version of the views made from the row (``api/services/views.py``). In an UPDATE every
    # right-hand side reads the row as it was, so it is the counter's new value.
    change_number: Mapped[int] = mapped_column(
        sa.BigInteger, default=0, server_default="0", onupdate=sa.text("trial_changes + 1")
    )

    trials: Mapped[list[TrialRow]] = relationship(
        back_populates="study", cascade="all, delete-orphan", passive_deletes=True, lazy="raise"
    )


class TrialRow(Base):
    """One simulation of a study: one individual, one replicate, one seed; and its result."""

    __tablename__ = "trials"
    __table_args__ = (
        # The trial list's order: pages are read straight off this index, no sort per request.
        sa.Index("ix_trials_study_order", "study_id", "generation", "individual", "replicate"),
        sa.Index("ix_trials_study_updated", "study_id", "updated_at"),
        sa.Index("ix_trials_study_change", "study_id", "change_number"),
        sa.Index("ix_trials_study_pareto", "study_id", "pareto"),
        # The recommendation's matching trials (f1 within tolerance), not a scan of the study's.
        sa.Index("ix_trials_study_f1", "study_id", "f1_value"),
        sa.UniqueConstraint("study_id", "individual", "replicate"),
    )

    id: Mapped[str] = mapped_column(sa.String(100), primary_key=True)
    study_id: Mapped[str] = mapped_column(sa.ForeignKey("studies.id", ondelete="CASCADE"))
    individual: Mapped[int]
    generation: Mapped[int]
    replicate: Mapped[int]
    seed: Mapped[int] = mapped_column(sa.BigInteger)
    params: Mapped[dict[str, Any]]
    scenario: Mapped[dict[str, Any]] = mapped_column(deferred=True)
    timeout_s: Mapped[float | None]
    state: Mapped[str] = mapped_column(sa.String(16), index=True)
    # Result fields, copied out of the JSON result so that lists and plots need no JSON parsing.
    status: Mapped[str | None] = mapped_column(sa.String(16))
    n_remaining: Mapped[int | None]
    responses: Mapped[dict[str, Any] | None]  # the scenario's named responses (migration 0004)
    engine: Mapped[str] = mapped_column(sa.String(32), default="numba", server_default="numba")
    engine_options: Mapped[dict[str, Any] | None]
    wall_time_s: Mapped[float | None]
    cost: Mapped[float | None]
    # The result's full_load_factor (1 until there is one, as a result without it reads): with
    # wall_time_s and cost it gives the whole protocol's, which f2 ranks (optimizer/objectives.py
    # protocol_cost), so that the dashboard draws what was ranked without the JSON result (0010).
    full_load_factor: Mapped[float] = mapped_column(default=1.0, server_default="1")
    dt: Mapped[float | None]
    result: Mapped[dict[str, Any] | None] = mapped_column(deferred=True)
    message: Mapped[str] = mapped_column(sa.Text, default="")
    worker: Mapped[str | None] = mapped_column(sa.String(200))
    attempts: Mapped[int] = mapped_column(default=0)
    pareto: Mapped[bool] = mapped_column(default=False)
    f1_value: Mapped[float | None]
    f1_kind: Mapped[str | None] = mapped_column(sa.String(8))
    f2_value: Mapped[float | None]
    f2_kind: Mapped[str | None] = mapped_column(sa.String(8))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)
    # The study's change number of the last write to this trial: the driver's cursor.
    change_number: Mapped[int] = mapped_column(sa.BigInteger, default=0, server_default="0")
    started_at: Mapped[datetime | None]
    finished_at: Mapped[datetime | None]

    study: Mapped[StudyRow] = relationship(back_populates="trials", lazy="raise")


class ShapeRow(Base):
    """An uploaded mesh (bytes kept in the database), its validation report and clump summary."""

    __tablename__ = "shapes"

    id: Mapped[str] = mapped_column(sa.String(64), primary_key=True)
    owner: Mapped[str | None] = mapped_column(sa.String(100), index=True)
    name: Mapped[str] = mapped_column(sa.String(200))
    file_type: Mapped[str] = mapped_column(sa.String(8))
    mass: Mapped[float]
    n_bytes: Mapped[int]
    sha256: Mapped[str] = mapped_column(sa.String(64))
    data: Mapped[bytes] = mapped_column(deferred=True)
    report: Mapped[dict[str, Any]]
    clump: Mapped[dict[str, Any] | None]
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class ApiKeyRow(Base):
    """An API key: only the sha256 of the token is stored, never the token."""

    __tablename__ = "api_keys"

    id: Mapped[int] = mapped_column(primary_key=True, autoincrement=True)
    name: Mapped[str] = mapped_column(sa.String(200), default="")
    owner: Mapped[str] = mapped_column(sa.String(100), index=True)
    prefix: Mapped[str] = mapped_column(sa.String(16))
    token_sha256: Mapped[str] = mapped_column(sa.String(64), unique=True)
    admin: Mapped[bool] = mapped_column(default=False)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    revoked_at: Mapped[datetime | None]
    last_used_at: Mapped[datetime | None]


class SimulationRow(Base):
    """A single simulation asked for through the API (not part of a study), and its result."""

    __tablename__ = "simulations"

    id: Mapped[str] = mapped_column(sa.String(64), primary_key=True)
    owner: Mapped[str | None] = mapped_column(sa.String(100), index=True)
    scenario: Mapped[dict[str, Any]]
    params: Mapped[dict[str, Any]]
    seed: Mapped[int] = mapped_column(sa.BigInteger)
    timeout_s: Mapped[float | None]
    state: Mapped[str] = mapped_column(sa.String(16), index=True)
    status: Mapped[str | None] = mapped_column(sa.String(16))
    n_remaining: Mapped[int | None]
    responses: Mapped[dict[str, Any] | None]
    engine: Mapped[str] = mapped_column(sa.String(32), default="numba", server_default="numba")
    wall_time_s: Mapped[float | None]
    result: Mapped[dict[str, Any] | None]
    worker: Mapped[str | None] = mapped_column(sa.String(200))
    attempts: Mapped[int] = mapped_column(default=0)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)
    finished_at: Mapped[datetime | None]
