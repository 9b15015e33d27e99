"""RLBench-style task suite in pybullet (Franka Panda, front + wrist cameras, TinyRenderer).

Modules: ``scene`` (world, robot, cameras, attach-on-close grasping), ``control`` (keyframe
controller: IK path + physics, failure flags), ``tasks`` (the task registry; three tasks are
planner-pretraining tasks), ``expert`` (scripted demonstrations recorded at 20 Hz), ``record``
(privileged per-frame state layout), ``gym_env`` (gymnasium API), ``generate`` (demo CLI with
disjoint split seed ranges), ``check_expert`` (success table), ``montage`` (first/middle/last
frames PNG).
"""
