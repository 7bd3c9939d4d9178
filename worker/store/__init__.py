"""The job store: the service's SQL schema and every SQL statement of it live in this package, one
module per concept. The API (server/) and the workers import it alike.

* :mod:`.schema`: the tables, the database clock, the engine set-up and the migrations;
* :mod:`.base`: the engine, the transactions, creating (and migrating) the tables;
* :mod:`.jobs`: submitting, reading, cancelling and deleting jobs;
* :mod:`.queue`: the queue protocol of the workers (claim, lease, fencing, the reaper);
* :mod:`.artifacts`: the artefacts stored in the database;
* :mod:`.workers`: the worker processes;
* :mod:`.studies`: studies and their jobs.

One code path for SQLite and PostgreSQL. Times are epoch seconds from the database's clock (``db_now``).
"""

from __future__ import annotations

from .artifacts import CHECKPOINT_NAME, ArtifactQueries, content_type_for
from .base import MAX_ID, Claim
from .jobs import JobQueries
from .queue import Beat, QueueProtocol
from .schema import TERMINAL_STATUSES, QueueFull
from .studies import StudyQueries
from .workers import WorkerQueries

__all__ = [
    "CHECKPOINT_NAME",
    "MAX_ID",
    "TERMINAL_STATUSES",
    "Beat",
    "Claim",
    "JobStore",
    "QueueFull",
    "content_type_for",
]


class JobStore(JobQueries, QueueProtocol, ArtifactQueries, WorkerQueries, StudyQueries):
    """Jobs, attempts, metrics, artefacts, workers and studies in one SQL database."""
