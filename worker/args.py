"""Command-line arguments of a worker (kept import-light: ``modsat --help`` loads this)."""

from __future__ import annotations

import argparse


def add_worker_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--db", metavar="URL", help="job store URL (default: MODSAT_DB_URL, or SQLite in --data-dir)")
    p.add_argument("--data-dir", help="directory of the default SQLite database (default ./modsat-data)")
    p.add_argument("--runner", help="train (default), noop, simulated, raise, or package.module:function")
    p.add_argument("--max-jobs", type=int, help="exit after this many attempts")
    p.add_argument("--idle-exit", type=float, metavar="S", help="exit after S seconds without work")
    p.add_argument("--exit-with-parent", type=int, metavar="PID", help=argparse.SUPPRESS)
