"""RLBench-style task suite in pybullet."""
