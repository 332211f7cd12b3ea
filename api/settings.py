"""demcal's settings, in one place: environment variables with the ``DEMCAL_`` prefix or a
``.env`` file in the working directory.

A bad value fails at start with a message naming the variable, never later in a request.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Literal

from pydantic import Field, ValidationError, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from worker.priority import DEFAULT_NICE

SNAPSHOT_SUBDIR = "snapshots"  # below data_dir: see Settings.snapshot_root

ENV_PREFIX = "DEMCAL_"


class SettingsError(ValueError):
    """A setting is missing or invalid; the message names the environment variable."""


class Settings(BaseSettings):
    """Everything an operator can configure. Defaults are the embedded mode: SQLite + local pool."""

    model_config = SettingsConfigDict(env_prefix=ENV_PREFIX, env_file=".env", extra="ignore")

    environment: Literal["development", "production"] = Field(
        "development", description="'production' refuses unsafe defaults (SQLite, open auth)."
    )
    database_url: str = Field(
        "sqlite:///demcal.db", description="SQLAlchemy URL of the store; SQLite file or PostgreSQL."
    )
    redis_url: str | None = Field(
        None, description="Redis URL of the job queue; unset means the embedded local process pool."
    )
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL"] = Field(
        "INFO", description="Level of the log lines written to stderr."
    )
    data_dir: Path = Field(
        Path("demcal-data"), description="Where results, snapshots, shapes and the clump cache live."
    )
    queue_name: str = Field("demcal", description="Name of the RQ queue the service posts trials to.")
    reconcile_interval_s: float = Field(
        30.0, gt=0, le=3600, description="Seconds between checks that queued trials are still queued."
    )
    lease_ttl_s: float = Field(
        30.0, ge=2, le=3600, description="Seconds before a dead `demcal serve`'s studies go to another."
    )
    workers: int = Field(0, ge=0, le=512, description="Local worker processes; 0 means one per core.")
    worker_nice: int = Field(
        DEFAULT_NICE, ge=0, le=19,
        description="Added to workers' nice value, so that DEM runs yield the CPU to the API; 0 = off.",
    )
    host: str = Field("127.0.0.1", description="Address `demcal serve` binds to.")
    port: int = Field(8000, ge=1, le=65535, description="Port `demcal serve` listens on.")
    max_request_bytes: int = Field(2_000_000, ge=1024, description="Largest accepted JSON body.")
    max_upload_bytes: int = Field(20_000_000, ge=1024, description="Largest accepted mesh upload.")
    max_mesh_faces: int = Field(2_000_000, ge=4, description="Most faces an uploaded mesh may have.")
    max_population: int = Field(500, ge=2, description="Largest GA population a study may ask for.")
    max_simulations: int = Field(5000, ge=1, description="Largest simulation budget of one study.")
    view_kept_studies: int = Field(
        64, ge=1,
        description="Studies whose progress and trial counts a server process keeps between polls "
        "(progress keeps each trial's record, about 4 kB a trial); a study polled after more others "
        "than this is read whole again.",
    )
    view_processes: int = Field(
        2, ge=0, le=8,
        description="Processes that build the polled views (recommendation, progress, Pareto front) "
        "off the server's process, so that no build holds its GIL while requests wait; 0 = on the "
        "server's threads.",
    )
    api_key_cache_s: float = Field(
        1.0, ge=0, le=60,
        description="Seconds a verified API key is remembered; a revoked key works at most this long.",
    )

    @field_validator("database_url")
    @classmethod
    def _known_database(cls, value: str) -> str:
        if not value.startswith(("sqlite", "postgresql")):
            raise ValueError("must be a sqlite:/// or postgresql:// URL")
        if value.startswith("postgresql://"):
            # psycopg 3 is the driver we ship; plain postgresql:// would ask for psycopg2.
            value = "postgresql+psycopg://" + value.removeprefix("postgresql://")
        return value

    @field_validator("redis_url")
    @classmethod
    def _redis_scheme(cls, value: str | None) -> str | None:
        if value in (None, ""):
            return None
        if not value.startswith(("redis://", "rediss://", "unix://")):
            raise ValueError("must be a redis://host:port/db URL (or unset for the local pool)")
        return value

    @model_validator(mode="after")
    def _safe_in_production(self) -> Settings:
        if self.environment == "production" and self.database_url.startswith("sqlite"):
            raise ValueError(
                "DEMCAL_DATABASE_URL: production needs PostgreSQL; SQLite is for the embedded mode"
            )
        return self

    @property
    def is_sqlite(self) -> bool:
        return self.database_url.startswith("sqlite")

    @property
    def snapshot_root(self) -> Path:
        """Where trials keep snapshots, one folder per trial id: workers write there
        (``keep_snapshots``) and the dashboard's replay reads there."""
        return self.data_dir / SNAPSHOT_SUBDIR


def load_settings(**overrides) -> Settings:
    """Read settings, turning pydantic's error into one that names the environment variable."""
    try:
        return Settings(**overrides)
    except ValidationError as exc:
        problems = []
        for err in exc.errors():
            field = str(err["loc"][0]) if err["loc"] else ""
            name = f"{ENV_PREFIX}{field.upper()}" if field else "settings"
            message = err["msg"].removeprefix("Value error, ")
            problems.append(message if message.startswith(ENV_PREFIX) else f"{name}: {message}")
        raise SettingsError("; ".join(problems)) from None


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """The process's settings, read once."""
    return load_settings()
