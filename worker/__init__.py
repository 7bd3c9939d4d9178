"""modsat's job queue: the SQL job store (worker.store), the artefact store (in the same
database), and the worker processes (worker.main, worker.attempt, worker.child).

``server`` -> ``worker`` -> ``modsat_core``: this package imports no web framework, and
torch only inside the training child process.
"""
