"""Trained agents as policies: checkpoints and the shipped navigators, and the datasets
recorded from any policy."""
