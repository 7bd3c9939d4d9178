"""Monte-Carlo evaluation, snapshot selection, a run's output files and the study report."""
