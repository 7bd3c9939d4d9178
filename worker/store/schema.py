"""The job store's schema and engine: one SQLAlchemy 2 schema for SQLite and PostgreSQL.

Only the URL differs between the two. Two dialect details are handled here, once:

* ``db_now()`` is the database's clock in epoch seconds. Leases are compared with it, so
  workers on several machines never compare their own clocks with each other.
* SQLite: WAL, a busy timeout, and ``BEGIN IMMEDIATE`` for write transactions (a
  transaction that reads first and then writes could otherwise fail with ``SQLITE_BUSY``
  instead of waiting). Read transactions use a plain ``BEGIN`` so readers never wait.
* Job ids are never given twice: ``AUTOINCREMENT`` on SQLite (without it SQLite hands the
  largest id out again once its job is deleted), a sequence on PostgreSQL.
  :func:`migrate_sqlite` rebuilds the jobs table of a store created before that.
* Submissions hold the queue (:func:`hold_queue`) from counting its active jobs to inserting
  theirs, so parallel submissions cannot take it past its cap.
"""

from __future__ import annotations

from pathlib import Path

from sqlalchemy import (
    BigInteger,
    Boolean,
    Column,
    Connection,
    Double,
    Engine,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    MetaData,
    String,
    Table,
    Text,
    create_engine,
    event,
    func,
    insert,
    select,
    text,
)
from sqlalchemy.engine import make_url
from sqlalchemy.ext.compiler import compiles
from sqlalchemy.schema import CreateIndex, CreateTable
from sqlalchemy.sql.functions import FunctionElement

metadata = MetaData()

#: Job ids are BIGINT on PostgreSQL; SQLite needs INTEGER for its rowid auto-increment.
_Id = BigInteger().with_variant(Integer(), "sqlite")

JOB_STATUSES = ("queued", "running", "succeeded", "failed", "cancelled")
TERMINAL_STATUSES = ("succeeded", "failed", "cancelled")

jobs = Table(
    "modsat_jobs",
    metadata,
    Column("id", _Id, primary_key=True, autoincrement=True),
    Column("name", String(200)),
    Column("algorithm", String(32), nullable=False),
    Column("spec", Text, nullable=False),  # JobSpec JSON
    Column("status", String(16), nullable=False, default="queued"),
    Column("created_at", Double, nullable=False),  # epoch seconds, database clock
    Column("updated_at", Double, nullable=False),
    Column("started_at", Double),  # first claim
    Column("finished_at", Double),
    # Claim and lease. `attempt` is the fencing token: +1 at every claim.
    Column("attempt", Integer, nullable=False, default=0),
    Column("failures", Integer, nullable=False, default=0),
    Column("max_attempts", Integer, nullable=False),
    Column("run_after", Double),  # retry back-off: not claimable before this
    Column("worker_id", String(200)),
    Column("lease_expires_at", Double),
    Column("heartbeat_at", Double),
    Column("cancel_requested", Boolean, nullable=False, default=False),
    # Progress, as last published by the lease holder.
    Column("last_seq", Integer, nullable=False, default=0),
    Column("env_steps", BigInteger, nullable=False, default=0),
    Column("total_env_steps", BigInteger, nullable=False),
    Column("phase", String(32)),
    Column("last_eval", Text),  # JSON of the latest learning-curve point
    Column("checkpoint_env_steps", BigInteger),
    Column("run_seconds", Double, nullable=False, default=0.0),  # wall time of finished attempts
    # Outcome.
    Column("summary", Text),  # JSON evaluation summary of a succeeded run
    Column("error", Text),
    Column("error_detail", Text),  # traceback of the last failed attempt
    sqlite_autoincrement=True,  # ids of deleted jobs are not given again
)
Index("ix_modsat_jobs_claim", jobs.c.status, jobs.c.id)

attempts = Table(
    "modsat_attempts",
    metadata,
    Column("job_id", _Id, ForeignKey("modsat_jobs.id", ondelete="CASCADE"), primary_key=True),
    Column("attempt", Integer, primary_key=True),
    Column("worker_id", String(200), nullable=False),
    Column("started_at", Double, nullable=False),
    Column("ended_at", Double),
    # running | succeeded | failed | crashed | lease-expired | cancelled | released
    Column("outcome", String(16), nullable=False),
    Column("resumed_from_env_steps", BigInteger),
    Column("error", Text),
)

metrics = Table(
    "modsat_metrics",
    metadata,
    Column("job_id", _Id, ForeignKey("modsat_jobs.id", ondelete="CASCADE"), primary_key=True),
    Column("seq", Integer, primary_key=True),  # per job, 1, 2, 3, ... (jobs.last_seq)
    Column("attempt", Integer, nullable=False),
    Column("created_at", Double, nullable=False),
    Column("env_steps", BigInteger, nullable=False),
    Column("data", Text, nullable=False),  # JSON of the progress dict (+ elapsed_s)
)

artifacts = Table(
    "modsat_artifacts",
    metadata,
    Column("job_id", _Id, ForeignKey("modsat_jobs.id", ondelete="CASCADE"), primary_key=True),
    Column("name", String(200), primary_key=True),
    Column("kind", String(16), nullable=False),  # output | checkpoint
    Column("attempt", Integer, nullable=False),
    Column("size", BigInteger, nullable=False),
    Column("sha256", String(64), nullable=False),
    Column("content_type", String(100), nullable=False),
    Column("created_at", Double, nullable=False),
    Column("data", LargeBinary, nullable=False),
)

# A study: one spec run over several seeds and algorithms, each a job (POST /api/studies).
studies = Table(
    "modsat_studies",
    metadata,
    Column("id", _Id, primary_key=True, autoincrement=True),
    Column("name", String(200)),
    Column("spec", Text, nullable=False),  # JobSpec JSON; each job has its own seed and algorithm
    Column("seeds", Text, nullable=False),  # JSON list of ints
    Column("algorithms", Text, nullable=False),  # JSON list of str
    Column("created_at", Double, nullable=False),
)

study_jobs = Table(
    "modsat_study_jobs",
    metadata,
    Column("study_id", _Id, ForeignKey("modsat_studies.id", ondelete="CASCADE"), primary_key=True),
    Column("job_id", _Id, ForeignKey("modsat_jobs.id", ondelete="CASCADE"), primary_key=True),
    Column("algorithm", String(32), nullable=False),
    Column("seed", BigInteger, nullable=False),
)
Index("ix_modsat_study_jobs_job", study_jobs.c.job_id)

workers = Table(
    "modsat_workers",
    metadata,
    Column("id", String(200), primary_key=True),
    Column("hostname", String(200), nullable=False),
    Column("pid", Integer, nullable=False),
    Column("runner", String(200), nullable=False),
    Column("started_at", Double, nullable=False),
    Column("last_seen", Double, nullable=False),
    Column("expires_at", Double, nullable=False),  # counted as alive until then
    Column("job_id", _Id),
    Column("stopped_at", Double),
)


class db_now(FunctionElement):
    """The database server's clock, epoch seconds (float)."""

    type = Double()
    inherit_cache = True


@compiles(db_now, "sqlite")
def _db_now_sqlite(element, compiler, **kw):
    return "((julianday('now') - 2440587.5) * 86400.0)"


@compiles(db_now, "postgresql")
def _db_now_postgresql(element, compiler, **kw):
    return "CAST(EXTRACT(EPOCH FROM clock_timestamp()) AS DOUBLE PRECISION)"


class QueueFull(Exception):
    """A submission would take the queue past its cap; ``active`` jobs are queued or running."""

    def __init__(self, active: int):
        self.active = active
        super().__init__(f"{active} jobs are queued or running")


#: The key of the PostgreSQL advisory lock that submissions hold (any constant; "modsat" in ASCII).
_QUEUE_LOCK_KEY = 0x6D6F64736174


def hold_queue(conn: Connection, adding: int, max_active: int | None) -> None:
    """In a write transaction, before inserting ``adding`` jobs: wait until no other submission
    is between its count and its insert, then raise :class:`QueueFull` if the jobs do not fit.

    SQLite's write transactions already run one at a time (``BEGIN IMMEDIATE``); PostgreSQL's
    take a transaction-level advisory lock, released at commit or rollback."""
    if max_active is None:
        return
    if conn.dialect.name == "postgresql":
        conn.execute(select(func.pg_advisory_xact_lock(_QUEUE_LOCK_KEY)))
    active = conn.execute(
        select(func.count()).select_from(jobs).where(jobs.c.status.in_(("queued", "running")))
    ).scalar_one()
    if active + adding > max_active:
        raise QueueFull(int(active))


def insert_job(
    conn: Connection, spec_json: str, name: str | None, algorithm: str, total: int, max_attempts: int
) -> int:
    """Insert one queued job inside the caller's write transaction; returns its id."""
    now = db_now()
    return int(
        conn.execute(
            insert(jobs)
            .values(
                name=name,
                algorithm=algorithm,
                spec=spec_json,
                status="queued",
                created_at=now,
                updated_at=now,
                attempt=0,
                failures=0,
                max_attempts=max_attempts,
                cancel_requested=False,
                last_seq=0,
                env_steps=0,
                total_env_steps=total,
                run_seconds=0.0,
            )
            .returning(jobs.c.id)
        ).scalar_one()
    )


def migrate_sqlite(engine: Engine) -> None:
    """Give the jobs table of a SQLite store created by an older modsat ``AUTOINCREMENT``.

    SQLite cannot add it to a table, so the table is rebuilt in one transaction, the way the
    SQLite documentation describes (ALTER TABLE, "other kinds of table schema changes"): foreign
    keys off, a new table, the rows copied with their ids, the old table dropped, the new one
    renamed, its index made again, the references checked. Ids deleted before the migration
    may still come back once; none after it. Several processes may start at once: the check
    is repeated under the write lock."""
    if not _needs_autoincrement(engine):
        return
    new = jobs.to_metadata(MetaData(), name="modsat_jobs_new")
    columns = ", ".join(c.name for c in jobs.c)
    raw = engine.raw_connection()  # PRAGMA foreign_keys does nothing inside a transaction
    try:
        cur = raw.cursor()
        cur.execute("PRAGMA foreign_keys = OFF")
        try:
            cur.execute("BEGIN IMMEDIATE")
            try:
                if _needs_autoincrement(cur):
                    cur.execute(str(CreateTable(new).compile(dialect=engine.dialect)))
                    cur.execute(f"INSERT INTO modsat_jobs_new ({columns}) SELECT {columns} FROM modsat_jobs")
                    cur.execute("DROP TABLE modsat_jobs")
                    cur.execute("ALTER TABLE modsat_jobs_new RENAME TO modsat_jobs")
                    for index in jobs.indexes:
                        cur.execute(str(CreateIndex(index).compile(dialect=engine.dialect)))
                    broken = cur.execute("PRAGMA foreign_key_check").fetchall()
                    if broken:
                        raise RuntimeError(f"rebuilding modsat_jobs left rows without their job: {broken[:5]}")
                cur.execute("COMMIT")
            except BaseException:
                cur.execute("ROLLBACK")
                raise
        finally:
            cur.execute("PRAGMA foreign_keys = ON")
            cur.close()
    finally:
        raw.close()


def _needs_autoincrement(on) -> bool:
    """Whether the SQLite jobs table exists without AUTOINCREMENT (``on``: an engine or a cursor)."""
    query = "SELECT sql FROM sqlite_master WHERE type = 'table' AND name = 'modsat_jobs'"
    if isinstance(on, Engine):
        with on.connect() as conn:
            ddl = conn.execute(text(query)).scalar()
    else:
        row = on.execute(query).fetchone()
        ddl = row[0] if row else None
    return ddl is not None and "AUTOINCREMENT" not in ddl.upper()


def normalize_url(url: str) -> str:
    """``postgresql://`` means psycopg 3 here (SQLAlchemy's default driver would be psycopg2)."""
    u = make_url(url)
    if u.drivername in ("postgresql", "postgres"):
        u = u.set(drivername="postgresql+psycopg")
    return u.render_as_string(hide_password=False)


def make_engine(url: str, *, busy_timeout_s: float = 30.0) -> Engine:
    """An engine for ``url`` (SQLite file or PostgreSQL), configured for the job store."""
    url = normalize_url(url)
    u = make_url(url)
    if u.get_backend_name() == "sqlite":
        if u.database and u.database != ":memory:":
            Path(u.database).parent.mkdir(parents=True, exist_ok=True)
        engine = create_engine(
            url, pool_size=16, max_overflow=32, connect_args={"timeout": busy_timeout_s, "check_same_thread": False}
        )
        _configure_sqlite(engine, busy_timeout_s)
        return engine
    if u.get_backend_name() == "postgresql":
        return create_engine(url, pool_size=10, max_overflow=20, pool_pre_ping=True)
    raise ValueError(f"unsupported database URL {u.render_as_string()!r}: use sqlite:///PATH or postgresql://...")


def _configure_sqlite(engine: Engine, busy_timeout_s: float) -> None:
    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_conn, _record) -> None:
        # We emit BEGIN ourselves (below); pysqlite's own transaction handling is off.
        dbapi_conn.isolation_level = None
        cur = dbapi_conn.cursor()
        cur.execute(f"PRAGMA busy_timeout = {int(busy_timeout_s * 1000)}")
        cur.execute("PRAGMA journal_mode = WAL")
        cur.execute("PRAGMA synchronous = NORMAL")  # durable in WAL mode up to the last checkpoint
        cur.execute("PRAGMA foreign_keys = ON")
        cur.close()

    @event.listens_for(engine, "begin")
    def _on_begin(conn) -> None:
        immediate = conn.get_execution_options().get("modsat_write", False)
        conn.exec_driver_sql("BEGIN IMMEDIATE" if immediate else "BEGIN")
