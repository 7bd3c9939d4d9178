"""`train()` and the learners behind it: the TD3 trainer, TD3 control of a fixed design, the GA, checkpoints."""
