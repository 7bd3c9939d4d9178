"""Per-cell observations of the unified design + control MDP.

Every one of the C = N^3 grid cells is a "module" of the shared per-module network. A
cell's feature vector has a common part and a part per phase; the other phase's part is
zero (the paper pads both to the same length):

    common   type one-hot (3), grid position in [-1, 1] (3), distance from the current
             centre of mass / (N a) (1), phase flag (1: design), actuator count / C
             (1), module count / C (1), the current grid is a valid satellite (1)   11
    design   the 6 von Neumann neighbours' type one-hots (18; outside the grid counts as
             empty: the paper's padding layer), design progress d / D (1)           19
    control  q_BT (4), dq_BT/dt * 2 / rate_limit (4), omega_B / rate_limit (3),
             tanh(30 q_BT,v) (3), tanh(300 q_BT,v) (3), tanh(50 s/rad omega_B) (3),
             this cell's wheel momentum / scale (3)                                 23

The design part is the paper's (type, neighbours, position, distance). The control part is
the paper's ``{q_e, q_e', omega, position, distance}`` (position and distance in the common
part). The additions, written down in docs/learning.md: a fine-error channel
``tanh(30 q_v)`` that keeps sub-degree errors visible to the network, and a finer pair
(``tanh(300 q_v)``, ``tanh(50 omega)``) on the scale of the paper's 0.25 deg / 0.01 rad/s
success condition (a 0.25 deg error is 0.57 there, 0.01 rad/s is 0.46); the cell's own wheel
momentum (DESIGN.md); the actuator / module counts, without which a shared per-module
controller cannot know what share of the total torque is its own; and a validity flag,
without which no cell of a per-module critic can tell that the grid as a whole has no
actuator or is in pieces (validity is global; a cell's neighbourhood cannot show it).
Empty cells get all-zero control features.

With `training.observe_last_command` (TD3 under actuation delay) a flying row's cells carry six
more features, appended after these 53 (:data:`N_LAST_COMMAND`): the cell's own last command (the
action commanded at the previous control step, in [-1, 1]; zero on cells that are not wheel
units) and the mean last command of the satellite's wheel units (on every module). With one
control step of delay the torque acting now is that command, so only with it is the plant Markov
again (docs/learning.md, "TD3 under delay"). Zero at a flight's first step and on design rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from modsat_core.grid import ACTUATOR, EMPTY, valid_mask
from modsat_core.sim.mission import error_quaternion
from modsat_core.sim.morphology import mass_properties_batched

N_COMMON, N_DESIGN, N_CONTROL = 11, 19, 23
N_FEATURES = N_COMMON + N_DESIGN + N_CONTROL
FINE_GAIN = 30.0
#: Gains of the finer error and rate channels (1 / rad, s / rad).
FINER_GAIN = 300.0
RATE_GAIN = 50.0
#: Numbers of the satellite's state in the control part (all but the cell's wheel momentum).
N_CONTROL_GLOBAL = N_CONTROL - 3
#: Where a cell's control part (the satellite's `control_globals`, then the wheel) starts.
CONTROL_AT = N_COMMON + N_DESIGN
#: Features of the last command (`training.observe_last_command`), after the N_FEATURES: the cell's
#: own (3) and the mean over the satellite's wheel units (3).
N_LAST_COMMAND = 6


def control_globals(
    q_BT: Tensor,
    omega_B: Tensor,
    rate_limit_rad_s: float,
    fine_gain: float = FINE_GAIN,
    finer_gain: float = FINER_GAIN,
    rate_gain: float = RATE_GAIN,
) -> Tensor:
    """(B, 20) the satellite-wide control features from the error quaternion and body rate.

    One function for the training features, the flat controller of ``bench control`` and
    the TorchScript export (it is scriptable: hence the gains as default arguments), so the
    three cannot drift apart.
    """
    w, v = q_BT[:, :1], q_BT[:, 1:]
    qdot = torch.cat(
        (-0.5 * (v * omega_B).sum(-1, keepdim=True), 0.5 * (w * omega_B + torch.cross(v, omega_B, dim=-1))), dim=-1
    )
    return torch.cat(
        (
            q_BT,
            qdot * (2.0 / rate_limit_rad_s),
            omega_B / rate_limit_rad_s,
            torch.tanh(fine_gain * v),
            torch.tanh(finer_gain * v),
            torch.tanh(rate_gain * omega_B),
        ),
        dim=-1,
    )


def mirror_control(x: Tensor, at: int = CONTROL_AT, n: int = N_CONTROL_GLOBAL, tail: int = 0) -> Tensor:
    """``x`` (..., F) with the :func:`control_globals` numbers at ``at:at + n`` (a cell's, by
    default) mirrored: the features of the same satellite with the error vector q_v and the
    body rate negated (the inverse error, turning the other way; `training.odd_control`).
    The last ``tail`` numbers (the last command's, :data:`N_LAST_COMMAND`, where observed) are
    negated: the mirrored satellite was commanded the opposite torque. Everything else is kept.

    q_v, omega and their tanh channels flip; q_w and dq_w/dt (-q_v . omega / 2) do not;
    dq_v/dt = (q_w omega + q_v x omega) / 2 becomes -dq_v/dt + q_v x omega. The map is its own
    inverse, and it fixes exactly the states with q_v = 0 and omega = 0: the pointed, still
    satellite (and the zero features of empty cells and design rows).
    """
    g = x[..., at : at + n]
    v, rate = g[..., 1:4], g[..., 8:11]  # q_v and omega / rate limit
    qdot_v = -g[..., 5:8] + 2.0 * torch.cross(v, rate, dim=-1)  # qdot is scaled by 2 / rate limit
    m = torch.cat((g[..., :1], -v, g[..., 4:5], qdot_v, -g[..., 8:]), dim=-1)
    if tail > 0:
        end = x.shape[-1] - tail
        return torch.cat((x[..., :at], m, x[..., at + n : end], -x[..., end:]), dim=-1)
    return torch.cat((x[..., :at], m, x[..., at + n :]), dim=-1)


@dataclass
class CellObs:
    """A batch of per-cell observations.

    Attributes:
        x: (B, C, F) features.
        act_mask: (B, C) bool, cells whose action has an effect (all cells while designing,
            actuator cells while flying).
        value_mask: (B, C) bool, cells averaged into the satellite's value (all cells while
            designing, non-empty cells while flying).
        design: (B,) bool, phase flag.
    """

    x: Tensor
    act_mask: Tensor
    value_mask: Tensor
    design: Tensor

    def index(self, idx: Tensor) -> CellObs:
        return CellObs(self.x[idx], self.act_mask[idx], self.value_mask[idx], self.design[idx])

    def rows(self, start: int, stop: int) -> CellObs:
        """Rows ``start:stop`` as views (no copy)."""
        return CellObs(
            self.x[start:stop], self.act_mask[start:stop], self.value_mask[start:stop], self.design[start:stop]
        )


@dataclass
class PhysState:
    """The satellite's global physical state as stored in the replay buffer (B rows)."""

    q_BN: Tensor  # (B, 4)
    q_TN: Tensor  # (B, 4)
    omega_B: Tensor  # (B, 3)
    h_cells: Tensor  # (B, C, 3) wheel momentum of each cell / h_scale (zeros without wheels)


def _one_hot(t: Tensor) -> Tensor:
    return torch.nn.functional.one_hot(t.long(), 3).to(torch.float32)


def grid_geometry(N: int, device: torch.device) -> Tensor:
    """(C, 3) normalised cell positions in [-1, 1] (all zeros for N = 1)."""
    idx = torch.arange(N, device=device, dtype=torch.float32)
    half = max((N - 1) / 2.0, 0.5)
    g = (idx - (N - 1) / 2.0) / half
    gi, gj, gk = torch.meshgrid(g, g, g, indexing="ij")
    return torch.stack((gi, gj, gk), dim=-1).reshape(-1, 3)


def neighbour_types(grids: Tensor) -> Tensor:
    """(B, C, 6) types of the six face neighbours, empty outside the grid."""
    B, N = grids.shape[0], grids.shape[1]
    p = torch.nn.functional.pad(grids, (1, 1, 1, 1, 1, 1), value=EMPTY)
    c = slice(1, N + 1)
    nb = [p[:, 2:, c, c], p[:, :-2, c, c], p[:, c, 2:, c], p[:, c, :-2, c], p[:, c, c, 2:], p[:, c, c, :-2]]
    return torch.stack([n.reshape(B, -1) for n in nb], dim=-1)


def cell_observation(
    grids: Tensor,
    design_step: Tensor,
    design_steps: int,
    phys: PhysState,
    rate_limit_rad_s: float,
    last_command: Tensor | None = None,
) -> CellObs:
    """Features of B satellites, each in its own phase.

    Args:
        grids: (B, N, N, N) integer cell types.
        design_step: (B,) long; d < design_steps while designing, >= design_steps flying.
        phys: global physical state (ignored for rows that are designing).
        last_command: (B, C, 3) the action commanded at the previous control step, or None: the
            :data:`N_LAST_COMMAND` features are appended only when it is given (module docstring).
    """
    B, N = grids.shape[0], grids.shape[1]
    C = N**3
    dev = grids.device
    flat = grids.reshape(B, C)
    design = design_step < design_steps
    pos = grid_geometry(N, dev).expand(B, C, 3)
    # Centre of mass of the current grid, in the same normalised units; an empty grid uses
    # the grid centre.
    _, com_m, _ = mass_properties_batched(grids, 1.0, 1.0, dtype=torch.float32)
    half = max((N - 1) / 2.0, 0.5)
    com = (com_m - (N - 1) / 2.0) / half
    count = (flat != EMPTY).sum(dim=1)
    com = torch.where((count > 0).unsqueeze(-1), com, torch.zeros_like(com))
    dist = (pos - com.unsqueeze(1)).norm(dim=-1, keepdim=True) * (half / N)

    # Only designing rows can be invalid: a satellite flies only if its grid was valid.
    valid = torch.ones(B, dtype=torch.bool, device=dev)
    if bool(design.any()):
        valid[design] = valid_mask(grids[design])
    per_sat = torch.stack(
        (
            design.to(torch.float32),
            (flat >= ACTUATOR).sum(dim=1).to(torch.float32) / C,
            count.to(torch.float32) / C,
            valid.to(torch.float32),
        ),
        dim=-1,
    )
    common = torch.cat((_one_hot(flat), pos, dist, per_sat.unsqueeze(1).expand(B, C, 4)), dim=-1)

    dpart = torch.zeros(B, C, N_DESIGN, device=dev)
    if bool(design.any()):  # the design part of the designing rows only (most rows fly)
        rows = design.nonzero().squeeze(-1)
        nb = _one_hot(neighbour_types(grids[rows])).reshape(len(rows), C, 18)
        prog = (design_step[rows].to(torch.float32) / design_steps).reshape(-1, 1, 1).expand(len(rows), C, 1)
        dpart[rows] = torch.cat((nb, prog), dim=-1)

    fly = ~design
    if bool(fly.any()):
        q_e = error_quaternion(phys.q_TN, phys.q_BN).to(torch.float32)
        glob = control_globals(q_e, phys.omega_B.to(torch.float32), rate_limit_rad_s)
        # zero on empty cells and on designing rows
        keep = ((flat != EMPTY) & fly.unsqueeze(-1)).unsqueeze(-1).to(torch.float32)
        cpart = torch.cat((glob.unsqueeze(1).expand(B, C, N_CONTROL_GLOBAL), phys.h_cells.to(torch.float32)), dim=-1)
        cpart = cpart * keep
    else:
        cpart = torch.zeros(B, C, N_CONTROL, device=dev)
    parts = [common, dpart, cpart]
    if last_command is not None:
        parts.append(last_command_features(flat, fly, last_command))
    x = torch.cat(parts, dim=-1)

    act_mask = torch.where(design.unsqueeze(-1), torch.ones_like(flat, dtype=torch.bool), flat >= ACTUATOR)
    value_mask = torch.where(design.unsqueeze(-1), torch.ones_like(flat, dtype=torch.bool), flat != EMPTY)
    return CellObs(x=x, act_mask=act_mask, value_mask=value_mask, design=design)


def last_command_features(flat: Tensor, fly: Tensor, last_command: Tensor) -> Tensor:
    """(B, C, 6) the last command's features of flat grids (B, C) whose rows ``fly`` (B,): each wheel
    unit's own command, and the mean over the wheel units on every module; zero on design rows."""
    units = (flat >= ACTUATOR) & fly.unsqueeze(-1)
    own = last_command.to(torch.float32) * units.unsqueeze(-1).to(torch.float32)
    n = units.sum(dim=1, keepdim=True).clamp(min=1).to(torch.float32)
    mean = own.sum(dim=1) / n
    keep = ((flat != EMPTY) & fly.unsqueeze(-1)).unsqueeze(-1).to(torch.float32)
    return torch.cat((own, mean.unsqueeze(1).expand_as(own) * keep), dim=-1)
