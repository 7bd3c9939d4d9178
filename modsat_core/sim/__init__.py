"""Physics and the mission: quaternions, batched rigid-body dynamics with reaction wheels, mass
properties of a grid, the slew simulator, the PD baseline, the gymnasium envs."""
