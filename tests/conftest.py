"""Hooks for every test package."""

from __future__ import annotations

import pytest


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_makereport(item, call):
    rep = yield
    setattr(item, f"rep_{rep.when}", rep)  # lets fixtures see whether the test failed (process_factory)
    return rep


def pytest_collection_modifyitems(config, items):
    """Every test of tests/web drives a real browser: marked ``browser``.

    The files marked ``slow`` (training runs of minutes to half an hour) run first, in collection
    order: with ``-n auto --dist loadfile --no-loadscope-reorder`` (the README's command) each
    worker starts on one of them and the fast files fill in behind. xdist's default order (files
    with the most tests first) started the 28-minute co-design file last, with the other worker
    idle for most of it.
    """
    for item in items:
        if "tests/web/" in item.nodeid.replace("\\", "/"):
            item.add_marker(pytest.mark.browser)
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)  # stable: slow first
