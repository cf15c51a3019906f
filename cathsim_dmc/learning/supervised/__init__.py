"""Supervised learning from recorded episodes: datasets (collect, data), behavioural
cloning of an image policy (bc) and contact-force prediction (force)."""
