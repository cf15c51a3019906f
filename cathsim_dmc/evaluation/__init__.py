"""Rollouts, the paper's metrics, episode ends, trajectory files, reports, plots and the model's physical checks."""
