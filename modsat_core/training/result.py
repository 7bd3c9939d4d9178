"""What :func:`modsat_core.training.train.train` returns (docs/train-interface.md)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class RunResult:
    """What :func:`train` returns. ``artifacts()`` is empty for a stopped run."""

    stopped: bool
    env_steps: int
    curve: list[dict] = field(default_factory=list)
    files: dict[str, bytes] = field(default_factory=dict)
    summary: dict = field(default_factory=dict)

    def artifacts(self) -> dict[str, bytes]:
        return dict(self.files)
