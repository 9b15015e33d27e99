"""Experiment pipeline, evaluation and tables."""
