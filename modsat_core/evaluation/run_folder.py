"""The one reader of a run folder: the files ``modsat train --out DIR`` writes (or a job's stored
artefacts, the same files), each read through its record in :mod:`modsat_core.artefacts`. The
study report, ``modsat verify``, ``modsat eval``, ``modsat view`` and the viewer read runs here.

Torch-free (the viewer and the API use it): the policy files are handed out as bytes, for torch
to load where it is needed. Each use asks for the files it needs, so a run folder from before a
file existed (no ``policy_export.pt``, no ``trajectories.json``) still opens and only asking for
the missing file fails, with :class:`MissingRunFile` naming the folder and the file. A folder
that does not exist is a ``FileNotFoundError``; a file that is not in its format an
:class:`~modsat_core.artefacts.ArtefactError` naming it.
"""

from __future__ import annotations

import errno
import json
import os
from collections.abc import Mapping
from typing import Any

from modsat_core.artefacts import ArtefactError, CurveFile, DesignReport, EvaluationReport, Trajectories
from modsat_core.spec.jobspec import JobSpec, parse_spec


class MissingRunFile(ArtefactError):
    """A file that a use of the run needs is not in its folder."""


class RunFolder:
    """A run's files: a directory (``path``), or the same files in memory (``files``, a job's
    artefacts; ``path`` then names the run in messages, e.g. its job's URL). A name whose bytes
    are None counts as missing."""

    def __init__(self, path: str | os.PathLike[str], files: Mapping[str, bytes | None] | None = None):
        self.path = os.fspath(path)
        self._files = None if files is None else {k: v for k, v in files.items() if v is not None}
        if self._files is None and not os.path.isdir(self.path):
            raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), self.path)

    @property
    def name(self) -> str:
        """The folder's own name (the last part of its path)."""
        return os.path.basename(os.path.normpath(self.path))

    def has(self, name: str) -> bool:
        if self._files is not None:
            return name in self._files
        return os.path.isfile(os.path.join(self.path, name))

    def read_optional(self, name: str) -> bytes | None:
        """The bytes of ``name``, or None where the run has no such file."""
        if self._files is not None:
            return self._files.get(name)
        path = os.path.join(self.path, name)
        if not os.path.isfile(path):
            return None
        with open(path, "rb") as fh:
            return fh.read()

    def read(self, name: str) -> bytes:
        """The bytes of ``name``; :class:`MissingRunFile` where the run has none."""
        data = self.read_optional(name)
        if data is None:
            raise MissingRunFile(f"{self.path}: no {name} (not a finished run written by `modsat train --out`)")
        return data

    def _label(self, name: str) -> str:
        return f"{self.path}/{name}"

    def spec(self) -> JobSpec:
        """``spec.json``, validated (a spec error names the file)."""
        try:
            return parse_spec(self.read("spec.json"))
        except MissingRunFile:
            raise
        except ValueError as exc:
            raise ArtefactError(f"{self._label('spec.json')}: {exc}") from None

    def spec_data(self) -> dict[str, Any] | None:
        """``spec.json`` as plain JSON, not validated (None without one): what a viewer shows of
        a run, also one whose spec this version no longer accepts."""
        data = self.read_optional("spec.json")
        if data is None:
            return None
        try:
            out = json.loads(data)
        except ValueError as exc:
            raise ArtefactError(f"{self._label('spec.json')}: not JSON ({exc})") from None
        if not isinstance(out, dict):
            raise ArtefactError(f"{self._label('spec.json')}: not a JSON object")
        return out

    def design(self) -> DesignReport:
        return DesignReport.parse(self.read("design.json"), self._label("design.json"))

    def curve(self) -> CurveFile:
        return CurveFile.parse(self.read("curve.json"), self._label("curve.json"))

    def evaluation(self) -> EvaluationReport:
        return EvaluationReport.parse(self.read("evaluation.json"), self._label("evaluation.json"))

    def trajectories(self) -> Trajectories:
        return Trajectories.parse(self.read("trajectories.json"), self._label("trajectories.json"))
