"""Training runs: the loop that joins the env core and the learner, checkpoints, metrics."""
