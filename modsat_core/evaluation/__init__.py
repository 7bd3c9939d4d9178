"""Monte-Carlo evaluation, snapshot selection, a run's output files, the one reader of a run folder
and the study report."""
