"""What runs report: ``results.json`` (:mod:`.results`, :mod:`.result_blocks`), the tables
(:mod:`.table_builders`, :mod:`.table_format`), plots (:mod:`.plots`) and paired statistics
(:mod:`.stats`)."""
