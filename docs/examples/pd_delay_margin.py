"""The sweep behind docs/robustness.md, "PD with a delay margin": PD's rate-gain cap ``c T`` against
success and violations with one control step of actuation delay, on the 3-actuator 3x3x3 design.

    OMP_NUM_THREADS=1 python docs/examples/pd_delay_margin.py 1.0 0.5 0.42
"""

from __future__ import annotations

import sys

from modsat_core.bench.learners import DESIGNS
from modsat_core.evaluation.monte_carlo import monte_carlo, monte_carlo_conditions
from modsat_core.sim.pd import PDController, pd_gains
from modsat_core.sim.slew import Design
from modsat_core.spec.evaluation import STANDARD_CONDITIONS
from modsat_core.spec.presets import get_preset


def main(caps: list[float]) -> None:
    spec = get_preset("cpu-3x3x3")
    design = Design.from_grid(DESIGNS["three-actuator"](), spec.modules)
    m, mods = spec.mission, spec.modules
    print("cap c T | nominal success | nominal settling s | delay-1 success | delay-1 violations")
    for cap in caps:

        class PD(PDController):
            def __init__(self, sim, cap=cap):
                self.gains = pd_gains(sim, rate_gain_max=cap)

        nominal = monte_carlo(design, PD, m, mods, episodes=100, seed=12345).summary()
        late = monte_carlo_conditions(design, PD, m, mods, [STANDARD_CONDITIONS["delay-1"]], episodes=100, seed=12345)
        d = late["delay-1"].summary()
        print(
            f"{cap:g} | {100 * nominal['success_rate']:.0f} % | {nominal['median_settling_time_s']:.2f} | "
            f"{100 * d['success_rate']:.0f} % | {d['safety_violations']}"
        )


if __name__ == "__main__":
    main([float(a) for a in sys.argv[1:]] or [1.0, 0.75, 0.5, 0.44, 0.42, 0.4, 0.3])
