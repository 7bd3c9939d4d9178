"""modsat's job queue: the job store (worker.store: the SQL schema, the queries and the
artefacts in the same database; the API imports it too), the worker processes (worker.main,
worker.attempt, worker.child) and what a job runs (worker.runners; the default,
worker.train_runner, is also what ``modsat train`` runs).

``server`` -> ``worker`` -> ``web`` -> ``modsat_core``: this package imports no web framework,
and torch only inside the training child process.
"""
