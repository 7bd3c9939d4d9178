"""Where the live viewer finds runs: the :class:`RunSource` protocol, and :class:`DirRuns` for
``modsat view`` (the job store's source, for ``modsat serve``, is server/hosting.py's)."""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

from ..run import RunData


class RunSource(Protocol):
    """Where the viewer finds runs. Keys are strings (a job id, a directory's index)."""

    def choices(self) -> list[tuple[str, str]]:
        """(key, label) of the runs that can be shown, newest first."""

    def load(self, key: str) -> RunData:
        """The run ``key``; raises KeyError if there is no such run."""

    def defaults(self, choices: list[tuple[str, str]]) -> tuple[str | None, str | None]:
        """The runs a new tab shows when it asks for none, given ``choices()``: (main, compare or None)."""


class DirRuns:
    """Runs from directories written by ``modsat train --out DIR`` (keys "1", "2", ...)."""

    def __init__(self, paths: list[str | Path]):
        self.paths = [Path(p) for p in paths]
        self._runs = [RunData.from_dir(p) for p in self.paths]  # fail early on a bad directory

    def choices(self) -> list[tuple[str, str]]:
        return [(str(i + 1), f"{p.name} ({r.short_algorithm})") for i, (p, r) in enumerate(zip(self.paths, self._runs))]

    def load(self, key: str) -> RunData:
        try:
            i = int(key) - 1
        except ValueError:
            raise KeyError(key) from None
        if not 0 <= i < len(self._runs):
            raise KeyError(key)
        return self._runs[i]

    def defaults(self, choices: list[tuple[str, str]]) -> tuple[str | None, str | None]:
        return (choices[0][0] if choices else None, choices[1][0] if len(choices) > 1 else None)
