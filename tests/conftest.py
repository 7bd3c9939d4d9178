"""Hooks for every test package."""

from __future__ import annotations

import pytest


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_makereport(item, call):
    rep = yield
    setattr(item, f"rep_{rep.when}", rep)  # lets fixtures see whether the test failed (process_factory)
    return rep


def pytest_collection_modifyitems(config, items):
    """Every test of tests/web drives a real browser: marked ``browser``."""
    for item in items:
        if "tests/web/" in item.nodeid.replace("\\", "/"):
            item.add_marker(pytest.mark.browser)
