"""The standalone export: torch only, in a fresh process, the same actions as modsat's."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from modsat_core.agent.networks import NETWORKS, make_actor
from modsat_core.agent.policy import PolicyController, export_torchscript
from modsat_core.codesign.features import N_FEATURES
from modsat_core.evaluation.monte_carlo import episode_rngs
from modsat_core.sim.mission import draw_episode
from modsat_core.sim.slew import Design, SlewSim

from .conftest import tiny_spec

SCRIPT = """
import sys, torch
m = torch.jit.load(sys.argv[1])
d = torch.load(sys.argv[2])
with torch.no_grad():
    torch.save(m(d["q_BT"], d["omega_B"], d["h_B"]), sys.argv[3])
assert "modsat_core" not in sys.modules
"""


@pytest.mark.parametrize("odd_control", [False, True])
@pytest.mark.parametrize("network", NETWORKS)
def test_export_matches_in_process_policy(tmp_path, network, odd_control):
    spec = tiny_spec(design={"grid_size": 3})
    grid = np.ones((3, 3, 3), dtype=np.int64)
    grid[0, 1, 1] = grid[1, 1, 1] = grid[2, 0, 2] = 2
    torch.manual_seed(0)
    actor = make_actor(network, N_FEATURES, [32, 32], odd_control).eval()
    # A state with rates and wheel momentum: fly a few random steps first.
    sim = SlewSim.from_designs([Design.from_grid(grid, spec.modules)] * 16, spec.mission, spec.modules)
    sim.reset(list(range(16)), [draw_episode(r, spec.mission) for r in episode_rngs(1, 16)])
    gen = torch.Generator().manual_seed(0)
    for _ in range(5):
        sim.step(torch.rand((16, 3, 3), generator=gen) * 2 - 1)
    expected = PolicyController(actor, grid, spec)(sim) * spec.modules.torque_scale_Nm
    assert sim.state.h_B.abs().sum() > 0 and sim.state.omega_B.abs().sum() > 0

    (tmp_path / "policy_export.pt").write_bytes(export_torchscript(actor, grid, spec))
    torch.save(
        {"q_BT": sim.error_quaternion().float(), "omega_B": sim.state.omega_B.float(), "h_B": sim.state.h_B.float()},
        tmp_path / "state.pt",
    )
    subprocess.run(
        [
            sys.executable,
            "-c",
            SCRIPT,
            str(tmp_path / "policy_export.pt"),
            str(tmp_path / "state.pt"),
            str(tmp_path / "out.pt"),
        ],
        check=True,
        cwd=tmp_path,
    )
    got = torch.load(tmp_path / "out.pt")
    assert got.shape == (16, 3, 3)
    torch.testing.assert_close(got, expected.float(), atol=1e-5, rtol=1e-5)


class _Payload:
    """A pickle that would run code when loaded: what a malicious policy.pt could hold."""

    def __reduce__(self):
        import os

        return (os.system, ("touch /tmp/modsat-pwned",))


def test_a_crafted_policy_file_is_refused_without_running_it(tmp_path):
    import io
    import os

    from modsat_core.agent.policy_file import load_policy

    buf = io.BytesIO()
    torch.save({"format": "modsat-policy", "payload": _Payload()}, buf)
    if os.path.exists("/tmp/modsat-pwned"):
        os.remove("/tmp/modsat-pwned")
    with pytest.raises(ValueError, match="not a modsat policy file"):
        load_policy(buf.getvalue())
    assert not os.path.exists("/tmp/modsat-pwned"), "the pickle's code ran"
