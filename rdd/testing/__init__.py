"""Synthetic datasets with known contents, for tests and benchmarks (not for real work): LeRobot
v2.1 / v3.0 folders (:mod:`.lerobot_synth`) and native episodes (:mod:`.native_synth`); a folder's
files as bytes (:mod:`.trees`)."""
