"""RDD: retrieval-based demonstration decomposition (Yan et al., NeurIPS 2025).

The public API is this package's root::

    import rdd
    *train, new = rdd.load_episodes("rlbench", "path/to/open_drawer/all_variations/episodes")
    encoder, expert = rdd.load_encoder("effnet_lite0"), rdd.ExpertDecomposer()
    db = rdd.SubtaskDatabase.build(train, [expert.decompose(ep).segments for ep in train], encoder)
    found = rdd.RDDDecomposer(db, encoder).decompose(new)
    print(found.segments, rdd.evaluate(found.segments, expert.decompose(new).segments)["miou"])
"""

# Imported eagerly: none of these imports torch (it loads when an encoder runs), so `import rdd`
# costs about numpy's import (0.2 s), and every tool sees the names.
from rdd.data.episode import Episode
from rdd.data.load import episode_names, load_episodes
from rdd.database.model import SubtaskDatabase
from rdd.decomposers.base import Decomposer, Decomposition
from rdd.decomposers.expert import ExpertDecomposer
from rdd.decomposers.rdd import RDDDecomposer
from rdd.decomposers.uniform import UniformDecomposer
from rdd.decomposers.uvd import UVDDecomposer
from rdd.decomposers.vlm import VLMDecomposer
from rdd.encoders import Encoder, available_encoders, load_encoder
from rdd.metrics import evaluate_segmentation as evaluate

__all__ = [
    "Decomposer", "Decomposition", "Encoder", "Episode", "ExpertDecomposer", "RDDDecomposer",
    "SubtaskDatabase", "UVDDecomposer", "UniformDecomposer", "VLMDecomposer", "available_encoders",
    "episode_names", "evaluate", "load_encoder", "load_episodes",
]
