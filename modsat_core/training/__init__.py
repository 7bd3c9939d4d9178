"""`train()` (train.py) and the five learners behind it (TD3 co-design and control, the GA, the
first-order diffsim learners), with the run contract's pieces one module each: callbacks.py,
result.py (RunResult), checkpoint.py (the codec) and replay_layout.py (the replay buffer's fields)."""
