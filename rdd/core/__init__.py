"""The algorithms under the decomposers: the optimal-partition solver (:mod:`.solver`), RDD's interval
scores (:mod:`.scoring`), UVD's milestone search (:mod:`.milestones`) and the calibration of RDD's
options on a database's own held-out episodes (:mod:`.calibrate`)."""
