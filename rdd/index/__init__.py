"""Nearest-neighbour retrieval backends over the sub-task database."""
