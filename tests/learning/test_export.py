"""The standalone exports (TorchScript, torch.export, ONNX; docs/export.md): the same torque as
the policy flying in modsat's simulator, TorchScript in a fresh process that imports only torch,
ONNX in onnxruntime."""

from __future__ import annotations

import io
import logging
import subprocess
import sys

import numpy as np
import onnxruntime as ort
import pytest
import torch

from modsat_core.agent.export import INPUT_NAMES, export_files, export_torchscript
from modsat_core.agent.networks import NETWORKS, make_actor
from modsat_core.agent.policy import PolicyController, controller_for
from modsat_core.agent.policy_file import load_policy
from modsat_core.codesign.features import N_FEATURES
from modsat_core.evaluation.monte_carlo import episode_rngs
from modsat_core.grid import ACTUATOR
from modsat_core.sim import quaternion as quat
from modsat_core.sim.dynamics import State
from modsat_core.sim.mission import draw_episode
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.spec.jobspec import JobSpec
from modsat_core.training.train import train

from .conftest import tiny_spec
from .test_diffsim import TWO_WHEELS, tiny_diffsim

#: The largest difference, N m, allowed between an export's torque command (float32) and the
#: policy's in the simulator (float64), over 1,000 random states; docs/export.md has the measured ones.
EXPORT_ATOL_NM = 1e-6
EXPORTS = ("policy_export.pt", "policy_export.pt2", "policy_export.onnx")

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
    expected = PolicyController(actor, grid, spec.design, spec.mission)(sim) * spec.modules.torque_scale_Nm
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
    # the run's other formats, of the same controller
    files = export_files(actor, grid, spec)
    inputs = torch.load(tmp_path / "state.pt")
    for name, tau in run_exports(files, *(inputs[k] for k in INPUT_NAMES)).items():
        torch.testing.assert_close(tau, expected.float(), atol=1e-5, rtol=1e-5, msg=name)


def run_exports(files: dict[str, bytes], q_BT, omega_B, h_B) -> dict[str, torch.Tensor]:
    """Each export's torque command (B, K, 3) for float32 inputs: TorchScript and the torch.export
    program in torch, ONNX in onnxruntime."""
    inputs = (q_BT, omega_B, h_B)
    with torch.no_grad():
        out = {
            "policy_export.pt": torch.jit.load(io.BytesIO(files["policy_export.pt"]))(*inputs),
            "policy_export.pt2": torch.export.load(io.BytesIO(files["policy_export.pt2"])).module()(*inputs),
        }
    session = ort.InferenceSession(files["policy_export.onnx"], providers=["CPUExecutionProvider"])
    (tau,) = session.run(None, {name: t.numpy() for name, t in zip(INPUT_NAMES, inputs)})
    out["policy_export.onnx"] = torch.from_numpy(tau)
    return out


#: Tiny runs of each kind of policy, on a fixed design of two wheel units (TWO_WHEELS).
RUNS = {
    "td3": lambda: tiny_spec(
        algorithm="td3-control", design={"grid_size": 2, "design_steps": 3, "fixed_design": TWO_WHEELS}
    ),
    "diffsim-pd": lambda: tiny_diffsim(diffsim__base="pd"),
    "diffsim-none": lambda: tiny_diffsim(diffsim__base="none"),
}


@pytest.fixture(scope="module")
def run_files():
    """The files of a tiny run of each kind, trained once per module (when a test first asks)."""
    done: dict[str, dict[str, bytes]] = {}

    def get(kind: str) -> dict[str, bytes]:
        if kind not in done:
            done[kind] = train(RUNS[kind]()).artifacts()
        return done[kind]

    return get


def random_states(spec: JobSpec, n_wheels: int, n: int, seed: int = 0):
    """``n`` random flights: target and attitude uniform over the rotations, each rate component
    uniform within the rate limit, each wheel's momentum within its scale (capacity, else what
    one unit stores in a second at full torque). float64."""
    gen = torch.Generator().manual_seed(seed)
    q_TN = torch.nn.functional.normalize(torch.randn(n, 4, generator=gen, dtype=torch.float64), dim=-1)
    q_BN = torch.nn.functional.normalize(torch.randn(n, 4, generator=gen, dtype=torch.float64), dim=-1)
    omega_B = (2 * torch.rand(n, 3, generator=gen, dtype=torch.float64) - 1) * spec.mission.rate_limit_rad_s
    h_scale = spec.modules.momentum_capacity_Nms or spec.modules.torque_scale_Nm
    h_B = (2 * torch.rand(n, n_wheels, 3, generator=gen, dtype=torch.float64) - 1) * h_scale
    return q_TN, q_BN, omega_B, h_B


@pytest.mark.parametrize("kind", list(RUNS))
def test_every_export_gives_the_policys_torque_on_1000_random_states(run_files, kind):
    """The run's three exports against its policy (policy.pt) flying in the simulator: 1,000 random
    states, half of them with an error quaternion of negative w (the simulator passes w >= 0; the
    exports take either sign of the same attitude)."""
    files = run_files(kind)
    assert set(EXPORTS) <= set(files)
    actor, grid, spec = load_policy(files["policy.pt"])
    K, n, tau_max = int((grid == ACTUATOR).sum()), 1000, spec.modules.torque_scale_Nm
    q_TN, q_BN, omega_B, h_B = random_states(spec, K, n)
    sim = SlewSim.from_designs(
        [Design.from_grid(grid, spec.modules)] * n, spec.mission, spec.modules, dtype=torch.float64
    )
    sim.state, sim.q_TN = State(q_BN, omega_B, h_B, torch.zeros(n, dtype=torch.float64)), q_TN
    with torch.no_grad():
        expected = controller_for(actor, grid, spec)(sim).clamp(-1, 1) * tau_max  # SlewSim clips the action
    assert expected.abs().amax() > 100 * EXPORT_ATOL_NM  # the tolerance resolves the torques
    q_BT = quat.multiply(quat.conjugate(q_TN), q_BN)  # conj(q_TN) (x) q_BN, either sign of w
    assert 400 < int((q_BT[:, 0] < 0).sum()) < 600
    got = run_exports(files, q_BT.float(), omega_B.float(), h_B.float())
    diffs = {name: (tau.double() - expected).abs().max().item() for name, tau in got.items()}
    print(kind, {name: f"{d:.2g} N m" for name, d in diffs.items()})
    assert all(tau.shape == (n, K, 3) for tau in got.values())
    assert max(diffs.values()) <= EXPORT_ATOL_NM, diffs
    # the batch size is free: one state at a time gives the same
    one = run_exports(files, q_BT[:1].float(), omega_B[:1].float(), h_B[:1].float())
    for name, tau in one.items():
        torch.testing.assert_close(tau, got[name][:1], atol=1e-7, rtol=1e-6, msg=name)


@pytest.mark.parametrize("failing", ["onnx", "export"])
def test_a_format_that_cannot_be_written_is_left_out_with_a_warning(monkeypatch, caplog, failing):
    """The ONNX exporter without onnxscript, or torch.export failing (and ONNX with it): the
    formats are left out and the log says which and why; the others are written."""
    spec = RUNS["td3"]()
    grid = np.asarray(TWO_WHEELS)
    actor = make_actor(spec.training.network, N_FEATURES, spec.training.hidden_sizes).eval()

    def fails(*args, **kwargs):
        if failing == "onnx":
            raise ModuleNotFoundError("No module named 'onnxscript'")
        raise RuntimeError("an exporter bug")

    monkeypatch.setattr(torch.onnx if failing == "onnx" else torch.export, "export", fails)
    with caplog.at_level(logging.WARNING, logger="modsat_core.agent.export"):
        files = export_files(actor, grid, spec)
    if failing == "onnx":
        assert set(files) == {"policy_export.pt", "policy_export.pt2"}
        assert "policy_export.onnx left out" in caplog.text and "pip install onnx onnxscript" in caplog.text
    else:
        assert set(files) == {"policy_export.pt"}
        assert "policy_export.pt2 and policy_export.onnx left out" in caplog.text and "an exporter bug" in caplog.text


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
