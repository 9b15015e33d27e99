"""The run's configuration: its typed schema (:mod:`.schemas`), the check before any stage
(:mod:`.validate`), building components from their nodes (:mod:`.instantiate`) and ``run.py --help``."""
