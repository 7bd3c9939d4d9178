"""How much the design can matter on a mission: the PD baseline flown on a few 3x3x3 designs.

    python docs/examples/pd_designs.py [PRESET] [EPISODES]

PRESET's mission and modules (default cpu-3x3x3), the same seeded slews for every design;
prints each design's modules, actuators, success and mean return
(docs/lab/2026-12-04-80k-budget-rate-margin-design-value.md)."""

import sys

import numpy as np

from modsat_core.evaluation.monte_carlo import monte_carlo
from modsat_core.grid import ACTUATOR, STRUCTURE
from modsat_core.sim.pd import PDController
from modsat_core.sim.slew import Design
from modsat_core.spec.presets import get_preset


def cube(actuators):
    g = np.full((3, 3, 3), STRUCTURE, dtype=np.int8)
    for cell in actuators:
        g[cell] = ACTUATOR
    return g


def sparse(cells):
    g = np.zeros((3, 3, 3), dtype=np.int8)
    for cell in cells:
        g[cell] = STRUCTURE
    g[1, 1, 1] = ACTUATOR
    return g


FACES = [(0, 1, 1), (2, 1, 1), (1, 0, 1), (1, 2, 1), (1, 1, 0), (1, 1, 2)]
DESIGNS = {
    "full cube, centre actuator": cube([(1, 1, 1)]),
    "full cube, 2 actuators": cube([(1, 1, 1), FACES[0]]),
    "full cube, 3 actuators": cube([(1, 1, 1), *FACES[:2]]),
    "full cube, 7 actuators": cube([(1, 1, 1), *FACES]),
    "full cube, 27 actuators": np.full((3, 3, 3), ACTUATOR, dtype=np.int8),
    "one actuator module": sparse([]),
    "rod of 3": sparse([(1, 1, 0), (1, 1, 2)]),
    "cross of 7": sparse(FACES),
    "plate of 9": sparse([(1, j, k) for j in range(3) for k in range(3)]),
}

if __name__ == "__main__":
    spec = get_preset(sys.argv[1] if len(sys.argv) > 1 else "cpu-3x3x3")
    episodes = int(sys.argv[2]) if len(sys.argv) > 2 else 20
    print(f"{'design':<28} {'modules':>7} {'act.':>4} {'success':>8} {'return':>9} {'slew/bound':>10}")
    for name, grid in DESIGNS.items():
        mc = monte_carlo(
            Design.from_grid(grid, spec.modules), PDController, spec.mission, spec.modules, episodes=episodes, seed=1
        )
        s = mc.summary((spec.mission.tolerance_deg,))
        print(
            f"{name:<28} {int((grid > 0).sum()):>7} {int((grid == ACTUATOR).sum()):>4} "
            f"{100 * s['success_rate']:>7.0f}% {s['mean_return']:>9.1f} {s['median_slew_time_ratio']:>10.2f}"
        )
