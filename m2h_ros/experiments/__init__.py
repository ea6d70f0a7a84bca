"""Experiments of the supplementary material: evaluation jobs and the sweeps that run them."""
