import pytest

from worker.store import JobStore

from .helpers import db_url, pg, spawn_worker, sqlite_url  # noqa: F401 - fixtures


@pytest.fixture
def store(db_url):  # noqa: F811 - db_url is the fixture imported above
    """A job store on the parametrised database (SQLite, PostgreSQL), disposed after the test."""
    s = JobStore(db_url)
    yield s
    s.dispose()
