"""The sub-task database: its model (:mod:`.model`), how entries are cut from episodes (:mod:`.build`)
and how it is stored and read back (:mod:`.store`)."""

from rdd.database.model import SubtaskDatabase
from rdd.database.store import DatabaseError

__all__ = ["DatabaseError", "SubtaskDatabase"]
