"""LLaVA-family high-level planner."""
