"""Benchmarks (not tests), one module per ``modsat bench`` command: ``sim``, ``update``,
``training_runs`` (``learn`` and ``rl-vs-ga``: whole training runs over seeds), ``control``
(flat-MLP TD3 on one fixed design), ``learners``, ``designs``, ``pareto`` and ``codesign``."""
