import numpy as np
import torch

from modsat_core.sim import dynamics as dyn
from modsat_core.sim.morphology import mass_properties


def make_plant(
    I_B,
    *,
    K=1,
    tau_max=0.8,
    h_max=float("inf"),
    wheels=True,
    n=0.0,
    tau_res=(0.0, 0.0, 0.0),
    phase=0.0,
    dtype=torch.float64,
):
    I = torch.as_tensor(np.asarray(I_B), dtype=dtype).reshape(-1, 3, 3)
    B = I.shape[0]
    return dyn.Plant(
        I_B=I,
        I_B_inv=torch.linalg.inv(I),
        actuator_mask=torch.ones(B, K, dtype=torch.bool),
        tau_max_Nm=tau_max,
        h_max_Nms=h_max,
        wheels=wheels,
        n_rad_s=n,
        orbit_phase_rad=torch.full((B,), phase, dtype=dtype),
        tau_residual_B=torch.tensor(tau_res, dtype=dtype).expand(B, 3).clone(),
    )


def make_state(q, w, K=1, dtype=torch.float64):
    q = torch.as_tensor(np.asarray(q), dtype=dtype).reshape(-1, 4)
    B = q.shape[0]
    return dyn.State(
        q_BN=q,
        omega_B=torch.as_tensor(np.asarray(w), dtype=dtype).reshape(B, 3),
        h_B=torch.zeros(B, K, 3, dtype=dtype),
        t_s=torch.zeros(B, dtype=dtype),
    )


def asymmetric_inertia():
    """A lopsided 3x3x3 design: full inertia tensor with clearly non-zero products."""
    g = np.zeros((3, 3, 3), dtype=int)
    g[0, :, 0] = 1
    g[:, 0, 0] = 1
    g[0, 0, :] = 1
    g[2, 2, 0] = 1
    g[2, 1, 0] = 1
    g[0, 0, 0] = 2
    I = mass_properties(g).inertia_B_kgm2
    assert np.abs(I - np.diag(np.diag(I))).max() > 0.01
    return I
