"""Health and metrics: what an operator's probe and Prometheus scrape see.

Health never raises: each dependency is reported ``ok`` or with the error's class and message, and
the overall status is ``degraded`` (503) if any is not ok, or if jobs wait on the queue while no
worker is registered (``problem`` says which). Metrics are Prometheus text format 0.0.4,
computed from the database (the source of truth) and, when configured, the RQ queue's length.
"""

from __future__ import annotations

import logging

import sqlalchemy as sa

from api import __version__
from api.schemas import Health
from api.settings import Settings
from api.store import SqlStore
from optimizer.protocols import StudyStatus, TrialState

log = logging.getLogger(__name__)


def _redis(settings: Settings):
    import redis

    return redis.Redis.from_url(settings.redis_url, socket_connect_timeout=2, socket_timeout=2)


def health(store: SqlStore, settings: Settings) -> Health:
    try:
        with store.engine.connect() as connection:
            connection.execute(sa.text("SELECT 1"))
        database = "ok"
    except Exception as exc:  # noqa: BLE001 - a probe reports every failure, it never raises
        log.warning("health: database check failed: %s", exc)
        database = f"error: {exc.__class__.__name__}"
    redis_state, workers, queued = "not configured", None, None
    if settings.redis_url:
        try:
            from rq import Queue, Worker

            connection = _redis(settings)
            try:
                connection.ping()
                workers = Worker.count(connection=connection)
                queued = Queue(settings.queue_name, connection=connection).count
            finally:
                connection.close()
            redis_state = "ok"
        except Exception as exc:  # noqa: BLE001
            log.warning("health: redis check failed: %s", exc)
            redis_state = f"error: {exc.__class__.__name__}"
    problems = []
    if database != "ok":
        problems.append(f"database {database}")
    if redis_state not in ("ok", "not configured"):
        problems.append(f"redis {redis_state}")
    if workers == 0 and queued:
        # Work is waiting and nobody will do it: not ok, whatever the connections say.
        problems.append(f"{queued} jobs queued and no worker running; start `demcal worker`")
    return Health(
        status="degraded" if problems else "ok", database=database, redis=redis_state, workers=workers,
        queued=queued, problem="; ".join(problems) or None, version=__version__,
    )


def _escape(value: str) -> str:
    return value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")


def metrics_text(store: SqlStore, settings: Settings) -> str:
    lines = []

    def family(name: str, kind: str, help_text: str, samples: list[tuple[dict[str, str], float]]) -> None:
        lines.append(f"# HELP {name} {help_text}")
        lines.append(f"# TYPE {name} {kind}")
        for labels, value in samples:
            label_text = ",".join(f'{key}="{_escape(val)}"' for key, val in labels.items())
            lines.append(f"{name}{{{label_text}}} {value:g}" if label_text else f"{name} {value:g}")

    studies = store.study_status_counts()
    family(
        "demcal_studies", "gauge", "Studies by status.",
        [({"status": st.value}, studies.get(st.value, 0)) for st in StudyStatus],
    )
    trials = store.trial_state_counts()
    family(
        "demcal_trials", "gauge", "Trials by state.",
        [({"state": st.value}, trials.get(st.value, 0)) for st in TrialState],
    )
    family(
        "demcal_simulation_seconds_total", "counter",
        "Wall-clock seconds of every finished simulation (trials and single runs).",
        [({}, store.simulation_seconds_total())],
    )
    if settings.redis_url:
        try:
            from rq import Queue

            depth = Queue(settings.queue_name, connection=_redis(settings)).count
            family("demcal_queue_depth", "gauge", "Jobs waiting in the RQ queue.",
                   [({"queue": settings.queue_name}, depth)])
        except Exception as exc:  # noqa: BLE001 - metrics stay available without Redis
            log.warning("metrics: queue depth unavailable: %s", exc)
    return "\n".join(lines) + "\n"
