"""Figures of decompositions: the segment timeline (:mod:`.timeline`) and the robot's signals under it
(:mod:`.signals`)."""
