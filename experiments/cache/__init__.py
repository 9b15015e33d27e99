"""The stage cache: stage directories keyed by what made them (:mod:`.store`), the code part of
those keys (:mod:`.code_keys`) and the locks that let runs share it (:mod:`.locks`)."""
