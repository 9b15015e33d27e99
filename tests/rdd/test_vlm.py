"""VLM baseline against a real HTTP server on 127.0.0.1 that answers like a chat endpoint (fixture
``endpoint``, tests/rdd/conftest.py)."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from rdd.data.episode import Episode
from rdd.decomposers.vlm import VLMDecomposer, parse_keyframe_indices
from rdd.labelers.vlm_backends import (
    OpenAIChatBackend,
    TransformersVLMBackend,
    VLMError,
    subsample_indices,
)

SECRET = "sk-test-secret-value-123"


def episode(t=40):
    frames = np.zeros((t, 12, 16, 3), dtype=np.uint8)
    frames[..., 0] = np.arange(t, dtype=np.uint8)[:, None, None] * 5
    return Episode(name="demo", views={"front": frames}, goal="open the drawer")


def test_parsing():
    assert parse_keyframe_indices("Keyframes: [7, 3, 3, 99, -2] then [1]", 10) == [0, 3, 7, 9]
    assert parse_keyframe_indices("```json\n[ 4 ,5, ]\n```", 10) == [4, 5]
    with pytest.raises(VLMError, match="no list of integers"):
        parse_keyframe_indices("I think frames four and five.", 10)
    with pytest.raises(VLMError, match="no list"):
        parse_keyframe_indices("[]", 10)


def test_subsample_maps_back():
    idx = subsample_indices(100, 16)
    assert idx[0] == 0 and idx[-1] == 99 and len(idx) == 16 and np.all(np.diff(idx) > 0)
    assert subsample_indices(5, 16).tolist() == [0, 1, 2, 3, 4]


def test_decompose_through_http(endpoint, monkeypatch, caplog):
    monkeypatch.setenv("MY_VLM_KEY", SECRET)
    endpoint.script = [(200, "The keyframes are [2, 5] and the end.", 0)]
    dec = VLMDecomposer(base_url=endpoint.base_url, model="tiny-vlm", api_key_env="MY_VLM_KEY",
                        max_frames=8, retries=0)
    with caplog.at_level(logging.DEBUG):
        out = dec.decompose(episode(40))
    shown = subsample_indices(40, 8)
    assert out.keyframes == [int(shown[2]), int(shown[5]), 39]
    assert out.segments[0] == (0, int(shown[2]) + 1)
    req = endpoint.requests[0]
    assert req["path"] == "/v1/chat/completions" and req["auth"] == f"Bearer {SECRET}"
    content = req["body"]["messages"][0]["content"]
    assert req["body"]["model"] == "tiny-vlm"
    assert "segmented into multiple steps" in content[0]["text"] and "starts from 0" in content[0]["text"]
    assert "open the drawer" in content[0]["text"]
    images = [c for c in content if c["type"] == "image_url"]
    assert len(images) == 8 and images[0]["image_url"]["url"].startswith("data:image/png;base64,")
    assert SECRET not in caplog.text


def test_retries_then_success_and_timeout(endpoint, caplog):
    endpoint.script = [(500, "", 0), (503, "", 0), (200, "[1]", 0)]
    backend = OpenAIChatBackend(endpoint.base_url, "m", api_key_env=None, retries=2, backoff=0.01)
    assert backend.ask("p", [np.zeros((4, 4, 3), np.uint8)], ["Frame 0:"]) == "[1]"
    assert len(endpoint.requests) == 3
    endpoint.script = [(200, "[1]", 0.6), (200, "[1]", 0.6)]
    slow = OpenAIChatBackend(endpoint.base_url, "m", api_key_env=None, timeout=0.2, retries=1, backoff=0.01)
    with pytest.raises(VLMError, match="failed after 2 attempts"):
        slow.ask("p", [], [])
    endpoint.script = [(400, "", 0)]
    with pytest.raises(VLMError, match="HTTP 400"):
        OpenAIChatBackend(endpoint.base_url, "m", api_key_env=None, retries=3).ask("p", [], [])


def test_unusable_answer_is_a_clear_error(endpoint):
    endpoint.script = [(200, "Sorry, I cannot tell.", 0)]
    dec = VLMDecomposer(base_url=endpoint.base_url, model="m", api_key_env=None, retries=0)
    with pytest.raises(VLMError, match="'demo'.*no list of integers"):
        dec.decompose(episode(10))


def test_local_checkpoint_missing_is_clear(tmp_path):
    with pytest.raises(FileNotFoundError, match="VLM checkpoint"):
        TransformersVLMBackend(tmp_path / "nope")
    with pytest.raises(ValueError, match="base_url"):
        VLMDecomposer(base_url="", model="m")


def build_tiny_llava(out):
    """A randomly initialised, tiny LLaVA checkpoint folder (word-level tokenizer, 32 px images)."""
    torch = pytest.importorskip("torch")
    tokenizers = pytest.importorskip("tokenizers")
    tf = pytest.importorskip("transformers")
    words = ["<pad>", "<unk>", "<s>", "</s>", "<image>", "[", "]", ",", "0", "1", "2", "3",
             "Frame", ":", "USER", "ASSISTANT"]
    tok = tokenizers.Tokenizer(tokenizers.models.WordLevel(
        vocab={w: i for i, w in enumerate(words)}, unk_token="<unk>"))
    tok.pre_tokenizer = tokenizers.pre_tokenizers.Whitespace()
    tokenizer = tf.PreTrainedTokenizerFast(
        tokenizer_object=tok, unk_token="<unk>", pad_token="<pad>", bos_token="<s>",
        eos_token="</s>", extra_special_tokens={"image_token": "<image>"})
    template = ("{% for m in messages %}USER : {% for c in m['content'] %}"
                "{% if c['type'] == 'image' %}<image> {% else %}{{ c['text'] }} {% endif %}"
                "{% endfor %}{% endfor %}{% if add_generation_prompt %}ASSISTANT :{% endif %}")
    processor = tf.LlavaProcessor(
        image_processor=tf.CLIPImageProcessor(size={"shortest_edge": 32},
                                              crop_size={"height": 32, "width": 32}),
        tokenizer=tokenizer, patch_size=16, num_additional_image_tokens=1,
        vision_feature_select_strategy="default", chat_template=template)
    config = tf.LlavaConfig(
        vision_config=tf.CLIPVisionConfig(hidden_size=16, intermediate_size=32, num_hidden_layers=1,
                                          num_attention_heads=2, image_size=32, patch_size=16),
        text_config=tf.LlamaConfig(vocab_size=len(words), hidden_size=16, intermediate_size=32,
                                   num_hidden_layers=1, num_attention_heads=2,
                                   num_key_value_heads=2, max_position_embeddings=512,
                                   pad_token_id=0, bos_token_id=2, eos_token_id=3),
        image_token_index=4, vision_feature_select_strategy="default", vision_feature_layer=-1)
    torch.manual_seed(0)
    tf.LlavaForConditionalGeneration(config).save_pretrained(out)
    processor.save_pretrained(out)
    return out


@pytest.mark.slow
def test_local_transformers_checkpoint(tmp_path):
    ckpt = build_tiny_llava(tmp_path / "tiny-llava")
    dec = VLMDecomposer(backend="transformers", checkpoint=str(ckpt), max_frames=4,
                        max_new_tokens=6)
    answer = dec.backend.ask("Frame", [np.zeros((40, 40, 3), np.uint8)] * 2, ["Frame 0 :", "Frame 1 :"])
    assert isinstance(answer, str)  # random weights: any text (even empty) is a valid answer
    # Random weights: whatever it says either parses into segments or is a clear error.
    try:
        out = dec.decompose(episode(12))
    except VLMError as exc:
        assert "'demo'" in str(exc)
    else:
        assert out.segments[-1][1] == 12 and out.meta["backend"] == "transformers"


def test_backend_options_pass_the_option_check_and_are_checked_by_the_backend(tmp_path):
    from rdd.registry import check_option_names, component

    cls = component("decomposer", "vlm")
    check_option_names("decomposer", cls, {"backend": "transformers", "checkpoint": "x"})  # passed on
    with pytest.raises(FileNotFoundError, match="VLM checkpoint"):
        cls(backend="transformers", checkpoint=str(tmp_path / "none"))
    with pytest.raises(ValueError, match=r"unknown option\(s\) \['chekpoint'\].*checkpoint"):
        cls(backend="transformers", chekpoint=str(tmp_path))
