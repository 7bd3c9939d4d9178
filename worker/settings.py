"""Settings of the job service, read from ``MODSAT_*`` environment variables.

:class:`WorkerSettings` is what a worker needs; the API server's settings
(``server.settings.ServerSettings``) extend it. Every field is documented in
docs/service.md (the table there is this file, in words).
"""

from __future__ import annotations

import os
from pathlib import Path

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from modsat_core.spec.limits import GIB, Limits

DEFAULT_DATA_DIR = Path("modsat-data")
DB_FILE_NAME = "modsat.db"


def default_db_url(data_dir: Path) -> str:
    """The SQLite file of a one-machine deployment: ``<data_dir>/modsat.db``."""
    return f"sqlite:///{(Path(data_dir) / DB_FILE_NAME).resolve()}"


def default_job_memory_gib() -> float:
    """8 GiB, or half of this machine's memory where that is less (a job must leave room for
    the service, the other workers and the system)."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # not POSIX: the fixed default
        return 8.0
    return min(8.0, round(total / 2 / GIB, 1))


class WorkerSettings(BaseSettings):
    """Queue and worker settings (env prefix ``MODSAT_``)."""

    model_config = SettingsConfigDict(env_prefix="MODSAT_", extra="ignore")

    data_dir: Path = Field(DEFAULT_DATA_DIR, description="Where the default SQLite database lives.")
    db_url: str | None = Field(
        None,
        description="SQLAlchemy URL of the job store. Unset: SQLite file `<data_dir>/modsat.db`. "
        "`postgresql://user@host/db` uses psycopg 3.",
    )
    sqlite_busy_timeout_s: float = Field(30.0, gt=0, le=3600, description="How long SQLite waits for a lock.")
    lease_s: float = Field(30.0, gt=0.2, le=86_400, description="A claim is held this long without a heartbeat.")
    heartbeat_s: float | None = Field(None, gt=0, le=3600, description="Heartbeat period; unset = lease_s / 4.")
    max_attempts: int = Field(
        3, ge=1, le=100, description="Failed attempts (error, crash, lost lease) before a job is `failed`."
    )
    retry_delay_s: float = Field(
        5.0, ge=0, le=86_400, description="A failed attempt is retried no sooner than this (doubling each time)."
    )
    poll_s: float = Field(1.0, gt=0, le=60, description="How often an idle worker looks for work.")
    cancel_grace_s: float = Field(
        20.0, ge=0, le=3600, description="Time a training gets to stop after a cancel or shutdown, then it is killed."
    )
    runner: str = Field(
        "train",
        description="What a job runs: `train` (modsat_core.training.train.train), or `noop` / `simulated` / `raise` "
        "(test and benchmark runners in worker.runners), or `package.module:function`.",
    )

    torch_threads: int = Field(
        1,
        ge=1,
        le=256,
        description="Torch threads of each training process. One per process: on a busy machine more "
        "threads measured about 20x slower, not faster (docs/service.md).",
    )
    max_job_memory_gib: float | None = Field(
        default_factory=lambda: default_job_memory_gib(),
        gt=0,
        le=1 << 20,
        description="A spec whose estimated peak memory (replay buffer, update, stepping, evaluation; "
        "modsat_core/spec/limits.py) is larger is refused (422 at the API). Default: 8, or half the machine's "
        "memory if that is less. Empty = no limit.",
    )
    max_env_steps: int | None = Field(
        20_000_000, ge=1, description="Largest `training.total_env_steps` of one job. Unset = no limit."
    )
    max_evaluation_steps: int | None = Field(
        50_000_000,
        ge=1,
        description="Largest number of control steps a job's evaluations (curve and final, policy and PD) "
        "may fly. Unset = no limit.",
    )
    max_trajectory_steps: int | None = Field(
        200_000, ge=1, description="Largest `evaluation.trajectories` x `mission.episode_steps`. Unset = no limit."
    )

    max_job_hours: float | None = Field(
        48.0,
        gt=0,
        description="A spec whose estimated wall time (modsat_core/spec/limits.py `work`: hours on one CPU core, "
        "or `gpu_speedup` times faster where `training.device` is `auto` or `cuda`) is longer is refused. "
        "Empty = no limit.",
    )
    gpu_speedup: float = Field(
        30.0,
        ge=1,
        le=10_000,
        description="How much faster this deployment's workers run a job that may use a GPU than one CPU core; "
        "1 where no worker has a GPU (the paper presets then take weeks and are refused).",
    )
    max_checkpoints: int | None = Field(
        1000, ge=1, description="Most checkpoints one job may write (total_env_steps / checkpoint_every_steps)."
    )

    @field_validator(
        "max_job_memory_gib",
        "max_env_steps",
        "max_evaluation_steps",
        "max_trajectory_steps",
        "max_job_hours",
        "max_checkpoints",
        mode="before",
    )
    @classmethod
    def _empty_is_unset(cls, v: object) -> object:
        return None if isinstance(v, str) and not v.strip() else v

    def limits(self) -> Limits:
        """The per-job limits these settings set (modsat_core.spec.limits)."""
        mem = None if self.max_job_memory_gib is None else int(self.max_job_memory_gib * GIB)
        return Limits(
            max_memory_bytes=mem,
            max_env_steps=self.max_env_steps,
            max_evaluation_steps=self.max_evaluation_steps,
            max_trajectory_steps=self.max_trajectory_steps,
            max_job_hours=self.max_job_hours,
            gpu_speedup=self.gpu_speedup,
            max_checkpoints=self.max_checkpoints,
        )

    @model_validator(mode="after")
    def _resolve(self) -> WorkerSettings:
        if self.heartbeat_s is None:
            self.heartbeat_s = self.lease_s / 4
        if self.heartbeat_s >= self.lease_s:
            raise ValueError(f"heartbeat_s ({self.heartbeat_s}) must be shorter than lease_s ({self.lease_s})")
        return self

    @property
    def resolved_db_url(self) -> str:
        return self.db_url or default_db_url(self.data_dir)
