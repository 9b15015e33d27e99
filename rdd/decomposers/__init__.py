"""Demonstration decomposers: RDD and the baselines."""
