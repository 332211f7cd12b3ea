"""The SQL store: the optimiser's ``Store`` protocol on SQLAlchemy, plus the reads the API needs.

What it is for: every write a study, a trial or a single simulation goes through, each method one
transaction (``api.db.unit_of_work``), identical on SQLite and PostgreSQL. ``demcal calibrate``
and ``demcal serve`` use the same class, so the service shows studies run from the CLI.

What it must not do: decide business rules (which status transitions are allowed, what a valid
definition is: ``api/services/``), or know about HTTP.

One module per resource, mixed into ``SqlStore``: ``studies``, ``trials`` (the driver's writes),
``simulations``, ``shapes``, ``archive`` (a study as one JSON document, to move it between
databases) and ``reads`` (trial pages, summaries and counters for the API and
dashboard); ``base`` holds the session and the row conversions they share. ``leases`` (which
process drives a study: ``DatabaseLeases``) stands apart, used by ``serve``'s driver loop and
``calibrate``.
"""

from __future__ import annotations

from api.store.archive import StudyArchives
from api.store.base import ALL_OWNERS, Page, new_id
from api.store.reads import TRIAL_READ_COLUMNS, DashboardReads, TrialFilter
from api.store.shapes import ShapeStore
from api.store.simulations import SimulationStore
from api.store.studies import StudyStore
from api.store.trials import TrialStore

__all__ = ["ALL_OWNERS", "TRIAL_READ_COLUMNS", "Page", "SqlStore", "TrialFilter", "new_id"]


class SqlStore(StudyArchives, StudyStore, TrialStore, SimulationStore, ShapeStore, DashboardReads):
    """The store of studies, trials, shapes and single simulations in one SQL database."""
