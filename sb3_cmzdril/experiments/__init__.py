"""The paper's experiment: trial grid (methods x envs x seeds) and its report."""
