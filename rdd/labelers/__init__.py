"""Labelers: what names an interval of an episode as a sub-task instruction (:mod:`.base` is the
protocol; :mod:`.retrieval`, :mod:`.signals` and :mod:`.vlm` implement it; :mod:`.vlm_backends` are
the vision-language model clients the VLM labeler and decomposer share)."""
