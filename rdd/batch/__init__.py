"""Episode-by-episode work that resumes: staged parts beside an output (:mod:`.staging`), run in this
process, in local worker processes, or on a Ray cluster (:mod:`.ray_executor`). The CLI and the
server both use it."""
