"""Flying a run's slews in Basilisk beside modsat's simulator (`modsat verify --basilisk`)."""
