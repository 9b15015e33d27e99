"""LeRobot datasets (v2.1, v3.0): the reader (:mod:`.reader`), the dataset's files (:mod:`.dataset`,
:mod:`.layout`, :mod:`.video`, :mod:`.checks`), its sub-task rows (:mod:`.language`) and the writer of
an annotated copy (:mod:`.write`, :mod:`.convert`)."""
