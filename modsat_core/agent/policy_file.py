"""``policy.pt``: the trained actor, its design and the run's spec, as a file users share.

Read with ``torch.load(weights_only=True)``: tensors and plain data only.
"""

from __future__ import annotations

import io
import pickle

import numpy as np
import torch

from modsat_core.agent.diffsim_policy import (
    DIFFSIM_NETWORK,
    DIFFSIM_PD_NETWORK,
    N_DESIGN_INPUTS,
    N_DIFFSIM_INPUTS,
    DiffsimPolicy,
)
from modsat_core.agent.networks import make_actor
from modsat_core.codesign.features import N_FEATURES, N_LAST_COMMAND
from modsat_core.sim.pd import RATE_GAIN_MAX_NO_DELAY_MARGIN
from modsat_core.spec.jobspec import JobSpec, Training, is_diffsim

#: Version 2: the network is named in the file (``per-module`` or ``set``), 53 features (59 with
#: `training.observe_last_command`, which the file's spec says).
POLICY_VERSION = 2


def load_plain(data: bytes, what: str, allow: list | tuple = ()) -> object:
    """``torch.load(weights_only=True)`` of a file a user can download or hand back: tensors and
    plain data (and the ``allow``-ed globals) only; anything else is a ValueError naming ``what``."""
    try:
        with torch.serialization.safe_globals(list(allow)):
            return torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        raise ValueError(
            f"not a modsat {what}: it holds objects other than tensors and plain data, which are "
            f"not loaded (torch.load weights_only): {str(exc).splitlines()[-1][:200]}"
        ) from None


def _n_design(spec: JobSpec) -> int:
    conditioned = spec.diffsim.design_pool > 0 or spec.algorithm == "diffsim-codesign"
    return N_DESIGN_INPUTS if conditioned else 0


def n_last_of(training: Training) -> int:
    """The last command's features a TD3 spec's networks see (`training.observe_last_command`), else 0."""
    return N_LAST_COMMAND if training.observe_last_command else 0


def n_features_of(training: Training) -> int:
    """The per-cell features a TD3 spec's actor and critics see."""
    return N_FEATURES + n_last_of(training)


def network_of(spec: JobSpec) -> tuple[str, list[int], int]:
    """The network a spec's policy is: its name in ``policy.pt``, its widths and its inputs."""
    if is_diffsim(spec):
        name = DIFFSIM_PD_NETWORK if spec.diffsim.base == "pd" else DIFFSIM_NETWORK
        return name, list(spec.diffsim.hidden_sizes), N_DIFFSIM_INPUTS + _n_design(spec)
    return spec.training.network, list(spec.training.hidden_sizes), n_features_of(spec.training)


def new_actor(spec: JobSpec) -> torch.nn.Module:
    """The policy network of a spec: the first-order learner's controller (``diffsim.hidden_sizes``)
    or the co-design actor (``training.network``, ``hidden_sizes``, ``odd_control``,
    ``observe_last_command``)."""
    if is_diffsim(spec):
        return DiffsimPolicy(list(spec.diffsim.hidden_sizes), _n_design(spec))
    t = spec.training
    return make_actor(t.network, n_features_of(t), list(t.hidden_sizes), t.odd_control, n_last_of(t))


def actor_from_state(spec: JobSpec, state: dict) -> torch.nn.Module:
    """A CPU actor in eval mode holding ``state`` (a state dict of :func:`new_actor`'s actor)."""
    actor = new_actor(spec)
    actor.load_state_dict(state)
    actor.eval()
    return actor


def policy_bytes(actor: torch.nn.Module, grid: np.ndarray | None, spec: JobSpec) -> bytes:
    network, hidden, n_inputs = network_of(spec)
    buf = io.BytesIO()
    torch.save(
        {
            "format": "modsat-policy",
            "version": POLICY_VERSION,
            "spec": spec.model_dump(mode="json"),
            "grid": None if grid is None else np.asarray(grid).tolist(),
            "network": network,
            "hidden_sizes": hidden,
            "n_features": n_inputs,
            "actor": {k: v.detach().cpu() for k, v in actor.state_dict().items()},
            **({"pd_rate_gain_max": actor.pd_rate_gain_max} if isinstance(actor, DiffsimPolicy) else {}),
        },
        buf,
    )
    return buf.getvalue()


def load_policy(data: bytes) -> tuple[torch.nn.Module, np.ndarray | None, JobSpec]:
    """Read ``policy.pt``: the actor (CPU, eval mode), its design grid and the run's spec.

    A policy file is downloaded and shared, so it is read with ``weights_only=True``: tensors
    and plain data only; a pickle that would build other objects (and could run code) is
    refused."""
    d = load_plain(data, "policy file")
    if not isinstance(d, dict) or d.get("format") != "modsat-policy":
        raise ValueError("not a modsat policy file")
    inputs = (N_FEATURES, N_FEATURES + N_LAST_COMMAND, N_DIFFSIM_INPUTS, N_DIFFSIM_INPUTS + N_DESIGN_INPUTS)
    if d.get("version") != POLICY_VERSION or d.get("n_features") not in inputs:
        raise ValueError(
            f"policy file version {d.get('version')} ({d.get('n_features')} features) is from an "
            f"older modsat; this one reads version {POLICY_VERSION} ({N_FEATURES} features, or "
            f"{N_DIFFSIM_INPUTS} (+{N_DESIGN_INPUTS}) inputs for the first-order learner's "
            f"controller): train the run again"
        )
    spec = JobSpec.model_validate(d["spec"])
    if d.get("network") == DIFFSIM_NETWORK and is_diffsim(spec) and spec.diffsim.base != "none":
        # Written before `diffsim.base` existed (its spec has no such key): the network alone.
        spec = spec.model_copy(update={"diffsim": spec.diffsim.model_copy(update={"base": "none"})})
    actor = actor_from_state(spec, d["actor"])
    if isinstance(actor, DiffsimPolicy):
        # Files written before the PD law's delay margin was stated flew the older cap.
        actor.pd_rate_gain_max = float(d.get("pd_rate_gain_max", RATE_GAIN_MAX_NO_DELAY_MARGIN))
    grid = None if d["grid"] is None else np.asarray(d["grid"], dtype=np.int64)
    return actor, grid, spec
