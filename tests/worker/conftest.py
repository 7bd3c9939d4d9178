import pytest

from .helpers import db_url, pg, spawn_worker, sqlite_url  # noqa: F401 - fixtures


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_makereport(item, call):
    rep = yield
    setattr(item, f"rep_{rep.when}", rep)  # lets fixtures see whether the test failed
    return rep
