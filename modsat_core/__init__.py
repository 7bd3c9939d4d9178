"""modsat core: modular-satellite physics, the slew mission and (co-)design learning.

Importing this package registers the gymnasium env ``modsat/SatelliteSlew-v0``.
"""

from gymnasium.envs.registration import register, registry

from modsat_core.spec.jobspec import JobSpec, SpecError, parse_spec

__all__ = ["JobSpec", "SpecError", "parse_spec"]
__version__ = "0.1.0"

if "modsat/SatelliteSlew-v0" not in registry:
    register(id="modsat/SatelliteSlew-v0", entry_point="modsat_core.sim.gym_envs:SatelliteSlewEnv")
