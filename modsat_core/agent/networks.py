"""Actor and critic networks, and the one factory every user of a co-design network calls.

Two co-design architectures (``training.network``), both acting per cell of the grid on the
per-cell observations of :mod:`modsat_core.codesign.features`:

``per-module`` (the paper's Fig. 6)
    One trunk MLP run on every cell, a design head and a control head. Twin critics per
    cell too; a satellite's value is the masked mean of its cells' values. It pays for its
    width once per cell: 27x on 3x3x3, 125x on 5x5x5.

``set``
    The same per-cell decisions, with the wide layers run once per satellite: a small
    per-cell encoder, masked mean pooling over the satellite's cells, the wide layers over
    [pooled encoding, the satellite-wide features], then small per-cell heads, on the
    acting cells only, that see the cell's encoding and the satellite's output (each cell
    still chooses its own type and its own wheel torques, now with the whole satellite as
    context). The critic pools every module's state encoding and every acting cell's
    (features, action) encoding and runs the wide twin Q layers once; both twins' per-cell
    layers are one fused layer. Design and control have separate layers (no shared trunk)
    and the untrained design head grows structure (see :class:`SetActor`). Attention
    pooling (the paper's suggestion for large grids) is not built: the mean already keeps
    5x5x5 within the cost aim (docs/benchmarks.md).

Plain MLP pairs for flat observations (gymnasium tasks, ``bench control``) are in
:mod:`modsat_core.agent.flat_networks`; the layers both use in :mod:`modsat_core.agent.layers`.

Every actor has ``act(x, act_mask, value_mask, design)`` over plain tensors,
``control_on(x, value_mask, cells)``, the control actions of a fixed set of cells with no
data-dependent branch or shape (what the standalone exports run: TorchScript, torch.export,
ONNX; docs/export.md), and ``forward(obs: CellObs)``.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from modsat_core.agent.layers import effort, finish, imitation, masked_mean, mlp
from modsat_core.codesign.features import CellObs, mirror_control

NETWORKS: tuple[str, ...] = ("per-module", "set")
#: Width of the set network's per-cell encoder and heads.
SET_CELL_WIDTH = 32
#: Initial bias of the set actor's design head toward structure (see :class:`SetActor`).
DESIGN_STRUCTURE_BIAS = 1.0


# ----------------------------------------------------------------------------- per-module


class CellActor(nn.Module):
    """Shared trunk over per-cell features, a design head and a control head (paper Fig. 6).

    ``odd_control``: the control head's output is made odd under :func:`mirror_control`
    (`training.odd_control`): half the difference of its values on the features and on the
    mirrored features, before the tanh. ``n_last``: how many of the ``n_features`` are the last
    command's (:data:`~modsat_core.codesign.features.N_LAST_COMMAND` with
    `training.observe_last_command`, else 0), the last ones."""

    def __init__(self, n_features: int, hidden: list[int], odd_control: bool = False, n_last: int = 0):
        super().__init__()
        self.trunk = nn.Sequential(mlp([n_features, *hidden]), nn.ReLU())
        self.design_head = nn.Linear(hidden[-1], 3)
        self.control_head = nn.Linear(hidden[-1], 3)
        self.odd_control = odd_control
        self.n_last = n_last

    def act(self, x: Tensor, act_mask: Tensor, value_mask: Tensor, design: Tensor) -> Tensor:
        z = self.trunk(x)
        control = self.control_head(z)
        if self.odd_control and not bool(design.all()):  # design rows keep their design head's output
            control = 0.5 * (control - self.control_head(self.trunk(mirror_control(x, tail=self.n_last))))
        raw = torch.where(design.reshape(-1, 1, 1), self.design_head(z), control)
        return torch.tanh(raw) * act_mask.unsqueeze(-1).to(raw.dtype)

    def control_on(self, x: Tensor, value_mask: Tensor, cells: Tensor) -> Tensor:
        """(B, K, 3) the control actions of the cells ``cells`` (K,) of satellites that all fly:
        :meth:`act` without its data-dependent branches, for the export (``value_mask``: unused,
        the set actor's signature)."""
        xc = x[:, cells]
        control = self.control_head(self.trunk(xc))
        if self.odd_control:
            control = 0.5 * (control - self.control_head(self.trunk(mirror_control(xc, tail=self.n_last))))
        return torch.tanh(control)

    @torch.jit.unused  # the export compiles ``act``; CellObs is no TorchScript type
    def forward(self, obs: CellObs) -> Tensor:
        """(B, C, 3) actions in [-1, 1], zero on cells whose action has no effect."""
        return self.act(obs.x, obs.act_mask, obs.value_mask, obs.design)

    finish = staticmethod(finish)
    effort = staticmethod(effort)
    imitation = staticmethod(imitation)


class CellCritic(nn.Module):
    """Twin per-module critics; a satellite's value is the masked mean over its cells.

    Each cell's critic sees its features, its own action and the mean action of the cells
    whose actions act (the satellite's net command, per actuator). Without the last part
    only the actuator cells' values depend on the action at all: with one actuator in 27
    modules, 26/27 of the value would be blind to control and the actor's gradient
    diluted as much (docs/learning.md).
    """

    def __init__(self, n_features: int, hidden: list[int]):
        super().__init__()
        self.q1 = mlp([n_features + 6, *hidden, 1])
        self.q2 = mlp([n_features + 6, *hidden, 1])

    def forward(self, obs: CellObs, action: Tensor) -> tuple[Tensor, Tensor]:
        mean_a = masked_mean(action, obs.act_mask)
        xa = torch.cat((obs.x, action, mean_a.unsqueeze(1).expand_as(action)), dim=-1)
        w = obs.value_mask.to(xa.dtype)
        denom = w.sum(dim=1).clamp(min=1.0)
        q1 = (self.q1(xa).squeeze(-1) * w).sum(dim=1) / denom
        q2 = (self.q2(xa).squeeze(-1) * w).sum(dim=1) / denom
        return q1, q2


# ----------------------------------------------------------------------------- set


class _CellHead(nn.Module):
    """A small per-cell head over a cell's encoding and its satellite's wide output."""

    def __init__(self, cell_width: int, sat_width: int):
        super().__init__()
        self.cell = nn.Linear(cell_width, cell_width)
        self.sat = nn.Linear(sat_width, cell_width, bias=False)
        self.out = nn.Linear(cell_width, 3)

    def forward(self, enc: Tensor, sat: Tensor) -> Tensor:
        """``enc`` (M, cell_width) cells' encodings, ``sat`` (M, cell_width) their satellites' ``self.sat(z)``."""
        return self.out(torch.relu(self.cell(enc) + sat))


class _SetActorPhase(nn.Module):
    """One phase's actor: per-cell encoder, pooling, wide layers, per-cell head on acting cells.
    ``odd``: the head's output is made odd under :func:`mirror_control`, as :class:`CellActor`'s."""

    def __init__(self, n_features: int, hidden: list[int], cell_width: int, odd: bool = False, n_last: int = 0):
        super().__init__()
        self.encoder = nn.Sequential(nn.Linear(n_features, cell_width), nn.ReLU(inplace=True))
        self.wide = nn.Sequential(mlp([cell_width + n_features, *hidden]), nn.ReLU())
        self.head = _CellHead(cell_width, hidden[-1])
        self.odd = odd
        self.n_last = n_last

    def _encode(self, x: Tensor, value_mask: Tensor) -> tuple[Tensor, Tensor]:
        """Every cell's encoding (B, C, cell_width) and its satellite's ``head.sat`` output (B, cell_width)."""
        enc = self.encoder(x)
        # The satellite-wide features (state, counts, progress) are the same on every
        # occupied cell; their mean over the satellite is them.
        z = self.wide(torch.cat((masked_mean(enc, value_mask), masked_mean(x, value_mask)), dim=-1))
        return enc, self.head.sat(z)

    def _out(self, x: Tensor, value_mask: Tensor, rows: Tensor, cells: Tensor) -> Tensor:
        enc, sat = self._encode(x, value_mask)
        return self.head(enc[rows, cells], sat[rows])

    def on_cells(self, x: Tensor, value_mask: Tensor, cells: Tensor) -> Tensor:
        """(B, K, 3) :meth:`forward`'s actions of the cells ``cells`` (K,) of every satellite: the
        same acting cells in every row, so no shape depends on the data (the export)."""
        enc, sat = self._encode(x, value_mask)
        out = self.head(enc[:, cells], sat.unsqueeze(1))
        if self.odd:
            enc_m, sat_m = self._encode(mirror_control(x, tail=self.n_last), value_mask)
            out = 0.5 * (out - self.head(enc_m[:, cells], sat_m.unsqueeze(1)))
        return torch.tanh(out)

    def forward(self, x: Tensor, act_mask: Tensor, value_mask: Tensor) -> Tensor:
        idx = act_mask.nonzero()
        rows, cells = idx[:, 0], idx[:, 1]
        out = self._out(x, value_mask, rows, cells)
        if self.odd:
            out = 0.5 * (out - self._out(mirror_control(x, tail=self.n_last), value_mask, rows, cells))
        raw = torch.zeros(x.shape[0], x.shape[1], 3, dtype=x.dtype, device=x.device)
        raw[rows, cells] = torch.tanh(out)
        return raw


class SetActor(nn.Module):
    """Design and control actors of the set architecture, one per phase.

    Unlike the paper's shared trunk, the phases do not share layers, so that the design
    rows of a batch (a few percent, but with Q differences between designs of hundreds)
    cannot pull the controller's layers around; docs/lab/2026-12-01-settle-bonus-set-network.md says
    what was measured with and without. The heads run on the acting cells only (every cell
    while designing, the actuators while flying).
    """

    def __init__(
        self,
        n_features: int,
        hidden: list[int],
        odd_control: bool = False,
        n_last: int = 0,
        cell_width: int = SET_CELL_WIDTH,
    ):
        super().__init__()
        self.n_last = n_last  # the last command's features, the last n_last (see CellActor)
        self.design = _SetActorPhase(n_features, hidden, cell_width)
        self.control = _SetActorPhase(n_features, hidden, cell_width, odd=odd_control, n_last=n_last)
        # The untrained design head grows structure everywhere (the full cube around the seed
        # actuator), not whatever type its random initialisation favours. Measured: from an
        # empty grid, runs whose first designs were all empty never left them (a one-module
        # satellite breaks the rate limit at once, and so does every design a few random cells
        # away from it), while runs that started from the full cube learned to fly it.
        with torch.no_grad():
            self.design.head.out.bias.copy_(torch.tensor([0.0, DESIGN_STRUCTURE_BIAS, 0.0]))

    def act(self, x: Tensor, act_mask: Tensor, value_mask: Tensor, design: Tensor) -> Tensor:
        if bool(design.all()):
            return self.design(x, act_mask, value_mask)
        fly = ~design
        if bool(fly.all()):
            return self.control(x, act_mask, value_mask)
        raw = torch.zeros(x.shape[0], x.shape[1], 3, dtype=x.dtype, device=x.device)
        raw[design] = self.design(x[design], act_mask[design], value_mask[design])
        raw[fly] = self.control(x[fly], act_mask[fly], value_mask[fly])
        return raw

    def control_on(self, x: Tensor, value_mask: Tensor, cells: Tensor) -> Tensor:
        """(B, K, 3) the control actions of the cells ``cells`` (K,) of satellites that all fly
        (:meth:`act` without its data-dependent branches, for the export)."""
        return self.control.on_cells(x, value_mask, cells)

    @torch.jit.unused
    def forward(self, obs: CellObs) -> Tensor:
        return self.act(obs.x, obs.act_mask, obs.value_mask, obs.design)

    finish = staticmethod(finish)
    effort = staticmethod(effort)
    imitation = staticmethod(imitation)


class _SetCriticPhase(nn.Module):
    """One phase's twin critics over pooled per-cell encodings, the wide Q layers once.

    The state of every module is encoded and pooled over the satellite; (features, action)
    of every acting cell is encoded and pooled over the acting cells; the mean action joins
    them directly (for one actuator it is that actuator's command). Both twins' per-cell
    layers are fused into one.
    """

    def __init__(self, n_features: int, hidden: list[int], cell_width: int):
        super().__init__()
        self.width = cell_width
        self.state_encoder = nn.Sequential(nn.Linear(n_features, 2 * cell_width), nn.ReLU(inplace=True))
        self.action_encoder = nn.Sequential(nn.Linear(n_features + 3, 2 * cell_width), nn.ReLU())
        self.q1 = mlp([2 * cell_width + n_features + 3, *hidden, 1])
        self.q2 = mlp([2 * cell_width + n_features + 3, *hidden, 1])

    def forward(self, x: Tensor, act_mask: Tensor, value_mask: Tensor, action: Tensor) -> tuple[Tensor, Tensor]:
        B = x.shape[0]
        e_all = masked_mean(self.state_encoder(x), value_mask)
        idx = act_mask.nonzero()
        rows, cells = idx[:, 0], idx[:, 1]
        a = action[rows, cells]
        count = act_mask.sum(dim=1, keepdim=True).clamp(min=1).to(x.dtype)
        ea = self.action_encoder(torch.cat((x[rows, cells], a), dim=-1))
        e_act = torch.zeros(B, ea.shape[1], dtype=x.dtype, device=x.device).index_add(0, rows, ea) / count
        mean_a = torch.zeros(B, 3, dtype=x.dtype, device=x.device).index_add(0, rows, a) / count
        sat = torch.cat((masked_mean(x, value_mask), mean_a), dim=-1)
        k = self.width
        q1 = self.q1(torch.cat((e_all[:, :k], e_act[:, :k], sat), dim=-1)).squeeze(-1)
        q2 = self.q2(torch.cat((e_all[:, k:], e_act[:, k:], sat), dim=-1)).squeeze(-1)
        return q1, q2


class SetCritic(nn.Module):
    """Twin critics of the set architecture, one pair per phase (see :class:`SetActor`)."""

    def __init__(self, n_features: int, hidden: list[int], cell_width: int = SET_CELL_WIDTH):
        super().__init__()
        self.design = _SetCriticPhase(n_features, hidden, cell_width)
        self.control = _SetCriticPhase(n_features, hidden, cell_width)

    def forward(self, obs: CellObs, action: Tensor) -> tuple[Tensor, Tensor]:
        d = obs.design
        if bool(d.all()):
            return self.design(obs.x, obs.act_mask, obs.value_mask, action)
        fly = ~d
        if bool(fly.all()):
            return self.control(obs.x, obs.act_mask, obs.value_mask, action)
        q1 = torch.zeros(d.shape[0], dtype=obs.x.dtype, device=obs.x.device)
        q2 = torch.zeros_like(q1)
        q1[d], q2[d] = self.design(obs.x[d], obs.act_mask[d], obs.value_mask[d], action[d])
        q1[fly], q2[fly] = self.control(obs.x[fly], obs.act_mask[fly], obs.value_mask[fly], action[fly])
        return q1, q2


# ----------------------------------------------------------------------------- factory

_ACTORS = {"per-module": CellActor, "set": SetActor}
_CRITICS = {"per-module": CellCritic, "set": SetCritic}


def _check(network: str) -> None:
    if network not in _ACTORS:
        raise ValueError(f"unknown network {network!r}; known: {', '.join(NETWORKS)}")


def make_actor(
    network: str, n_features: int, hidden: list[int], odd_control: bool = False, n_last: int = 0
) -> nn.Module:
    """The co-design actor of ``network`` (``per-module`` or ``set``); ``odd_control``: the
    control output is odd under :func:`mirror_control` (`training.odd_control`); ``n_last``: the
    last ``n_last`` of the ``n_features`` are the last command's (`training.observe_last_command`)."""
    _check(network)
    return _ACTORS[network](n_features, list(hidden), odd_control, n_last)


def observes_last_command(actor: nn.Module) -> bool:
    """Whether a co-design actor's features end with the last command's (`training.observe_last_command`):
    whatever flies it must give it the command it returned at the previous control step."""
    return int(getattr(actor, "n_last", 0)) > 0


def make_critic(network: str, n_features: int, hidden: list[int]) -> nn.Module:
    """The twin critic that goes with :func:`make_actor`'s actor."""
    _check(network)
    return _CRITICS[network](n_features, list(hidden))
