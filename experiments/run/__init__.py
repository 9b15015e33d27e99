"""One harness run: the pipeline (:mod:`.pipeline`), its stage graph (:mod:`.graph`,
:mod:`.planner_stages`), the modes (:mod:`.modes`), the closed-loop evaluation (:mod:`.evaluation`)
and the calls into the other packages (:mod:`.components`)."""
