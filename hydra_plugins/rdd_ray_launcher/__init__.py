"""Hydra launcher that runs each sweep job as a Ray task, on a local Ray cluster or an existing one."""
