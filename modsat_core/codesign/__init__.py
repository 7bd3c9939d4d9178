"""The co-design MDP (a design phase, then a control phase) and its per-cell observation features."""
