"""Learning: reinforcement learning (rl/) and supervised learning (supervised/), on the
networks and datasets they share (networks.py, datasets.py)."""
