"""Benchmarks (not tests): the simulator, one TD3 update, whole training runs."""
