"""A finished run as the viewer sees it, read from its stored JSON artefacts.

``design.json`` gives the grid (0 empty, 1 structure, 2 actuator); ``trajectories.json``
gives, per controller (``policy`` and ``pd_baseline``), the time histories of the first few
evaluation slews (modsat_core.evaluation.monte_carlo.monte_carlo): ``t_s`` (T,), ``q_BN`` (T, 4) scalar
first, ``omega_B`` (T, 3) rad/s, ``h_B`` (T, 3) wheel momentum in N m s, ``error_deg`` (T,),
``q_TN`` (4,) and the episode's ``metrics``. Both controllers fly the same seeded slews, and
so do two runs with the same evaluation seed: episode i is comparable across them. The files
are read through their models in modsat_core.artefacts, a run folder through
modsat_core.evaluation.run_folder (a file that is missing or does not fit raises
``ArtefactError``, a ``ValueError``, naming it).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from modsat_core.artefacts import DesignReport, EpisodeMetrics, EvaluationReport, Trajectories, Trajectory
from modsat_core.evaluation.run_folder import RunFolder
from modsat_core.grid import ACTUATOR, EMPTY

#: Controllers in ``trajectories.json`` and how the viewer names them.
CONTROLLERS = {"policy": "policy", "pd_baseline": "PD baseline"}


def learner_label(algorithm: str) -> str:
    """How the page and the viewer name a run's learner: ``RL`` (TD3), ``GA`` or ``diffsim``."""
    if algorithm == "ga":
        return "GA"
    if algorithm.startswith("td3"):
        return "RL"
    if algorithm.startswith("diffsim"):
        return "diffsim"
    return algorithm or "run"


@dataclass(frozen=True)
class Episode:
    """One recorded slew. Arrays are float64; quaternions scalar-first (viser's ``wxyz``)."""

    t_s: np.ndarray  # (T,) s
    q_BN: np.ndarray  # (T, 4)
    omega_B: np.ndarray  # (T, 3) rad/s
    h_B: np.ndarray  # (T, 3) N m s, total wheel momentum in the body frame
    error_deg: np.ndarray  # (T,) deg
    q_TN: np.ndarray  # (4,)
    metrics: dict = field(default_factory=dict)  # EpisodeMetrics as plain data

    @classmethod
    def from_record(cls, r: Trajectory) -> Episode:
        """From a slew of ``trajectories.json`` (a history it lacks reads as zeros)."""
        t = np.asarray(r.t_s, dtype=np.float64).reshape(-1)
        n = len(t)

        def arr(v: list | None, width: int) -> np.ndarray:
            return np.zeros((n, width)) if v is None else np.asarray(v, dtype=np.float64).reshape(n, width)

        return cls(
            t_s=t,
            q_BN=arr(r.q_BN, 4),
            omega_B=arr(r.omega_B, 3),
            h_B=arr(r.h_B, 3),
            error_deg=np.zeros(n) if r.error_deg is None else np.asarray(r.error_deg, dtype=np.float64),
            q_TN=np.asarray(r.q_TN or (1.0, 0.0, 0.0, 0.0), dtype=np.float64),
            metrics=(r.metrics or EpisodeMetrics()).to_dict(),
        )

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0]) if len(self.t_s) else 0.0

    @property
    def rate_rad_s(self) -> np.ndarray:
        """|omega_B|, (T,) rad/s."""
        return np.linalg.norm(self.omega_B, axis=1)

    @property
    def wheel_momentum_Nms(self) -> np.ndarray:
        """|h_B|, (T,) N m s."""
        return np.linalg.norm(self.h_B, axis=1)

    def indices_at(self, t_s: np.ndarray) -> np.ndarray:
        """For each time, the last sample at or before it (the first / last one outside the episode)."""
        i = np.searchsorted(self.t_s, np.asarray(t_s) + 1e-9, side="right") - 1
        return np.clip(i, 0, max(len(self.t_s) - 1, 0))

    def index_at(self, t_s: float) -> int:
        """:meth:`indices_at` of one time."""
        return int(self.indices_at(np.array([t_s]))[0])

    def describe(self) -> str:
        """One line for a picker: slew angle and outcome."""
        m = self.metrics
        angle = m.get("slew_angle_deg")
        parts = [f"{angle:.0f} deg slew" if isinstance(angle, (int, float)) else "slew"]
        if m.get("success"):
            parts.append("success")
        elif m.get("safety_violation"):
            parts.append("rate limit hit")
        err = m.get("final_error_deg")
        if isinstance(err, (int, float)) and math.isfinite(err):
            parts.append(f"final error {err:.2f} deg")
        return ", ".join(parts)


def payload_cells(spec: dict | None) -> list[tuple[int, int, int]]:
    """The payload's cells [i, j, k] named by a run's ``spec.json`` as plain JSON: the parts
    catalog's ``modules.payload.cells``, else (older co-design specs) ``objective.payload_cells``.
    Empty without a spec or a payload; an entry that is not three integers is skipped (the spec is
    not validated here: a run whose spec this version refuses is still shown)."""
    if not isinstance(spec, dict):
        return []
    modules, objective = spec.get("modules"), spec.get("objective")
    payload = modules.get("payload") if isinstance(modules, dict) else None
    cells = payload.get("cells") if isinstance(payload, dict) else None
    if not cells and isinstance(objective, dict):
        cells = objective.get("payload_cells")
    if not isinstance(cells, list):
        return []
    out = []
    for c in cells:
        if isinstance(c, (list, tuple)) and len(c) == 3 and all(type(v) is int for v in c):
            out.append((c[0], c[1], c[2]))
    return out


def sample_period(episodes: list[Episode]) -> float:
    """The shortest median sample period of the episodes, s (0.1 when none has two samples)."""
    dts = [float(np.median(np.diff(e.t_s))) for e in episodes if len(e.t_s) > 1]
    return min(dts) if dts else 0.1


@dataclass
class RunData:
    """Everything the viewer draws for one run."""

    title: str
    grid: np.ndarray  # (N, N, N) int: 0 empty, 1 structure, 2 actuator
    episodes: dict[str, list[Episode]]  # controller -> recorded slews
    design: DesignReport
    evaluation: EvaluationReport | None = None
    spec: dict | None = None

    @classmethod
    def of(
        cls,
        design: DesignReport,
        trajectories: Trajectories,
        *,
        evaluation: EvaluationReport | None = None,
        spec: dict | None = None,
        title: str | None = None,
    ) -> RunData:
        """From the artefacts' records."""
        episodes = {k: [Episode.from_record(e) for e in getattr(trajectories, k)] for k in CONTROLLERS}
        if title is None:
            title = (spec or {}).get("name") or (spec or {}).get("algorithm") or "run"
        return cls(title=title, grid=design.array, episodes=episodes, design=design, evaluation=evaluation, spec=spec)

    @classmethod
    def from_json(cls, design, trajectories, *, evaluation=None, spec=None, title: str | None = None) -> RunData:
        """From the artefacts' bytes (or already decoded JSON); ``ArtefactError`` if one is not in its format."""
        return cls.of(
            DesignReport.parse(design),
            Trajectories.parse(trajectories),
            evaluation=None if evaluation is None else EvaluationReport.parse(evaluation),
            spec=json.loads(spec) if isinstance(spec, (bytes, str)) else spec,
            title=title,
        )

    @classmethod
    def from_folder(cls, run: RunFolder, title: str | None = None) -> RunData:
        """From a run's folder (a directory, or a job's artefacts): ``design.json`` and
        ``trajectories.json`` needed, ``evaluation.json`` and ``spec.json`` where the run has them
        (the spec not validated: a run whose spec this version refuses is still shown)."""
        return cls.of(
            run.design(),
            run.trajectories(),
            evaluation=run.evaluation() if run.has("evaluation.json") else None,
            spec=run.spec_data(),
            title=title,
        )

    @classmethod
    def from_dir(cls, path: str | Path, title: str | None = None) -> RunData:
        """From a directory written by ``modsat train --out DIR`` (titled by its name)."""
        run = RunFolder(path)
        return cls.from_folder(run, title or run.name)

    @property
    def algorithm(self) -> str:
        return str((self.spec or {}).get("algorithm") or "")

    @property
    def short_algorithm(self) -> str:
        """``RL`` for the TD3 runs, ``GA`` for the genetic algorithm, ``diffsim`` for the first-order
        learner's."""
        return learner_label(self.algorithm)

    @property
    def payload_cells(self) -> list[tuple[int, int, int]]:
        """The payload's cells named by the run's spec (empty when it has none): see :func:`payload_cells`."""
        return payload_cells(self.spec)

    @property
    def controllers(self) -> list[str]:
        """Controllers that have recorded slews, policy first."""
        return [k for k in CONTROLLERS if self.episodes.get(k)]

    @property
    def modules(self) -> int:
        return int((self.grid != EMPTY).sum())

    @property
    def actuators(self) -> int:
        return int((self.grid >= ACTUATOR).sum())
