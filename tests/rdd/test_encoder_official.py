"""The paper's seven encoders: architecture output sizes, official checkpoint layouts, missing files.

Expected dimensions, file names, key names, shapes and key counts come from the official projects
(RDD's EmbedPreprocs table; torchvision's resnet50; openai/CLIP's ModifiedResNet; timm's ViT as used
by VC-1; DINOv2's hub ViT-L/14), not from this package's code.
"""

import numpy as np
import pytest
import torch

from rdd.encoders import load_encoder
from rdd.encoders._checkpoint import MissingCheckpointError

# RDD's rdd/embed.py EmbedPreprocs: name -> output dimension.
DIMS = {"liv": 1024, "r3m": 2048, "vip": 1024, "vc1": 768, "clip": 1024, "dinov2": 1024, "resnet": 1000}
FILES = {
    "liv": "model.pt", "r3m": "model.pt", "vip": "model.pt", "vc1": "vc1_vitb.pth", "clip": "RN50.pt",
    "dinov2": "dinov2_vitl14_pretrain.pth", "resnet": "resnet50-11ad3fa6.pth",
}
# Where each official project publishes its weights (a fragment the error message must contain).
SOURCES = {
    "liv": "jasonyma/LIV", "r3m": "facebookresearch/r3m", "vip": "pytorch.s3.amazonaws.com/models/rl/vip",
    "vc1": "dl.fbaipublicfiles.com/eai-vc/vc1_vitb.pth", "clip": "openaipublic.azureedge.net/clip/models",
    "dinov2": "dl.fbaipublicfiles.com/dinov2/dinov2_vitl14", "resnet": "download.pytorch.org/models/resnet50",
}
HEAVY = {"dinov2"}  # ViT-L: ~300M parameters, several seconds to build and run on 2 cores


def _marks(name):
    return [pytest.mark.slow] if name in HEAVY else []


ALL = [pytest.param(n, marks=_marks(n)) for n in DIMS]

_BUILT: dict = {}


def _random(name):
    """A random-weight build, shared across tests of this module (building ViT-L takes seconds).

    In torch: these tests check architectures and checkpoint layouts; exporting seven random
    networks to ONNX would only add minutes (test_encoder_runtime.py covers the ONNX path)."""
    if name not in _BUILT:
        _BUILT[name] = load_encoder(name, random_weights=True, seed=1, batch_size=1, num_threads=1, runtime="torch")
    return _BUILT[name]


@pytest.fixture(scope="module")
def image():
    return np.random.default_rng(0).integers(0, 256, size=(1, 96, 128, 3), dtype=np.uint8)


@pytest.mark.parametrize("name", ALL)
def test_random_build_has_documented_dim(name, image):
    enc = _random(name)
    out = enc.encode(image)
    assert enc.dim == DIMS[name]
    assert out.shape == (1, DIMS[name]) and out.dtype == np.float32
    assert np.isfinite(out).all() and np.abs(out).sum() > 0


def _torchvision_resnet(sd, prefix=""):
    return {prefix + k: v for k, v in sd.items()}


def _official_layout(name, sd):
    """Wrap a model state dict the way the official project's checkpoint file stores it, with the
    parts the image encoder does not use (language heads, text towers, MAE decoder) added."""
    z = torch.zeros(2)
    if name == "r3m":
        inner = _torchvision_resnet(sd, "module.convnet.")
        inner.update({"module.lang_enc.model.embeddings.word_embeddings.weight": z, "module.lang_rew.pred.0.weight": z})
        return {"r3m": inner}
    if name == "vip":
        return {"vip": _torchvision_resnet(sd, "module.convnet.")}
    if name == "liv":
        inner = {"module.model.visual." + k: v for k, v in sd.items()}
        inner.update({"module.model.token_embedding.weight": z, "module.model.logit_scale": z,
                      "module.model.transformer.resblocks.0.attn.in_proj_weight": z})
        return {"liv": inner}
    if name == "clip":
        out = {"visual." + k: v for k, v in sd.items()}
        out.update({"token_embedding.weight": z, "positional_embedding": z, "text_projection": z,
                    "logit_scale": z, "ln_final.weight": z, "transformer.resblocks.0.ln_1.weight": z})
        return out
    if name == "vc1":
        out = dict(sd)
        out.update({"mask_token": torch.zeros(1, 1, 768), "decoder_embed.weight": z, "decoder_pos_embed": z,
                    "decoder_blocks.0.norm1.weight": z, "decoder_norm.weight": z, "decoder_pred.weight": z})
        return {"model": out}
    return dict(sd)  # dinov2 and resnet: flat state dicts


# Keys (with shapes) that the official checkpoints contain, and the size of the image-tower part.
ANCHORS = {
    "resnet": ({"conv1.weight": (64, 3, 7, 7), "layer1.0.downsample.0.weight": (256, 64, 1, 1),
                "layer4.2.bn3.running_var": (2048,), "fc.weight": (1000, 2048)}, 320),
    "r3m": ({"module.convnet.layer3.5.conv2.weight": (256, 256, 3, 3)}, 318),
    "vip": ({"module.convnet.fc.weight": (1024, 2048), "module.convnet.fc.bias": (1024,)}, 320),
    "clip": ({"visual.conv1.weight": (32, 3, 3, 3), "visual.layer1.0.downsample.0.weight": (256, 64, 1, 1),
              "visual.attnpool.positional_embedding": (50, 2048), "visual.attnpool.c_proj.weight": (1024, 2048)}, 339),
    "liv": ({"module.model.visual.attnpool.q_proj.weight": (2048, 2048),
             "module.model.visual.layer4.0.downsample.1.running_mean": (2048,)}, 339),
    "vc1": ({"cls_token": (1, 1, 768), "pos_embed": (1, 197, 768), "patch_embed.proj.weight": (768, 3, 16, 16),
             "blocks.11.attn.qkv.weight": (2304, 768), "blocks.11.mlp.fc2.weight": (768, 3072), "norm.bias": (768,)}, 150),
    "dinov2": ({"pos_embed": (1, 1370, 1024), "mask_token": (1, 1024), "patch_embed.proj.weight": (1024, 3, 14, 14),
                "blocks.23.ls2.gamma": (1024,), "blocks.0.attn.qkv.weight": (3072, 1024)}, 343),
}


def _flat(obj, prefix=""):
    if isinstance(obj, dict) and not all(isinstance(v, torch.Tensor) for v in obj.values()):
        out = {}
        for v in obj.values():
            out.update(_flat(v))
        return out
    return obj


@pytest.mark.parametrize("name", ALL)
def test_official_layout_matches_model_strictly(name):
    """The official file's image-tower keys and shapes are exactly the model's (in memory)."""
    import importlib

    from rdd.encoders._checkpoint import load_strict

    src = _random(name)
    sd = src.model.state_dict()
    assert len(sd) == ANCHORS[name][1]
    ckpt = _official_layout(name, sd)
    flat = _flat(ckpt)
    for key, shape in ANCHORS[name][0].items():
        assert tuple(flat[key].shape) == shape, key
    spec = importlib.import_module(f"rdd.encoders.{name}").SPEC
    before = src.weights_id
    load_strict(src.model, spec.extract(ckpt, FILES[name]), name, FILES[name])
    assert src.weights_id == before


FILE_ROUNDTRIP = [pytest.param(n, marks=[] if n == "vip" else [pytest.mark.slow]) for n in DIMS]


@pytest.mark.parametrize("name", FILE_ROUNDTRIP)
def test_official_checkpoint_file_loads(name, image, tmp_path, monkeypatch):
    """A file in the official layout at $RDD_WEIGHTS_DIR/<name>/<file> loads strictly and reproduces
    the embeddings of the weights written into it."""
    src = _random(name)
    target = tmp_path / name / FILES[name]
    target.parent.mkdir()
    torch.save(_official_layout(name, src.model.state_dict()), target)
    monkeypatch.setenv("RDD_WEIGHTS_DIR", str(tmp_path))
    loaded = load_encoder(name, batch_size=1, num_threads=1, runtime="torch")
    assert loaded.weights_id == src.weights_id
    np.testing.assert_allclose(loaded.encode(image), src.encode(image), rtol=1e-5, atol=1e-5)


def test_liv_trainer_snapshot_without_dataparallel_prefix_loads(tmp_path):
    """LIV's trainer saves ``self.model.module.state_dict()`` (no ``module.``) plus optimizer state."""
    from rdd.encoders._checkpoint import load_state, load_strict
    from rdd.encoders.liv import SPEC

    src = _random("liv")
    inner = {"model.visual." + k: v for k, v in src.model.state_dict().items()}
    inner["model.logit_scale"] = torch.zeros([])
    path = tmp_path / "snapshot.pt"
    torch.save({"liv": inner, "optimizer": {"state": {}, "param_groups": [{"lr": 1e-5}]}, "global_step": 3}, path)
    load_strict(src.model, SPEC.extract(load_state(path, "liv"), path), "liv", path)


@pytest.mark.slow
def test_clip_torchscript_archive_loads(image, tmp_path):
    """OpenAI ships RN50.pt as a TorchScript archive; its state dict holds ``visual.*``."""
    src = _random("clip")

    class Wrapper(torch.nn.Module):
        def __init__(self, visual):
            super().__init__()
            self.visual = visual
            self.logit_scale = torch.nn.Parameter(torch.ones([]))

        def forward(self, x):
            return self.visual(x) * self.logit_scale

    traced = torch.jit.trace(Wrapper(src.model), torch.zeros(1, 3, 224, 224), check_trace=False)
    path = tmp_path / "RN50.pt"
    torch.jit.save(traced, str(path))
    loaded = load_encoder("clip", checkpoint=str(path), batch_size=1, runtime="torch")
    np.testing.assert_allclose(loaded.encode(image), src.encode(image), rtol=1e-5, atol=1e-5)


def test_layout_mismatch_is_reported(tmp_path):
    sd = _random("vip").model.state_dict()
    bad = {"vip": {**_torchvision_resnet(sd, "module.convnet."), "module.convnet.extra.weight": torch.zeros(1)}}
    torch.save(bad, tmp_path / "model.pt")
    with pytest.raises(ValueError, match="unexpected keys.*extra"):
        load_encoder("vip", checkpoint=str(tmp_path / "model.pt"))
    torch.save({"r3m": {}}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="'vip'"):
        load_encoder("vip", checkpoint=str(tmp_path / "other.pt"))


@pytest.mark.parametrize("name", list(DIMS))
def test_missing_checkpoint_message(name, tmp_path, monkeypatch):
    monkeypatch.delenv("RDD_WEIGHTS_DIR", raising=False)
    with pytest.raises(MissingCheckpointError) as err:
        load_encoder(name)
    msg = str(err.value)
    assert FILES[name] in msg and SOURCES[name] in msg
    assert "RDD_WEIGHTS_DIR" in msg and "checkpoint=" in msg
    monkeypatch.setenv("RDD_WEIGHTS_DIR", str(tmp_path))
    with pytest.raises(MissingCheckpointError, match=str(tmp_path / name / FILES[name])):
        load_encoder(name)
    with pytest.raises(MissingCheckpointError, match="nope.bin"):
        load_encoder(name, checkpoint=str(tmp_path / "nope.bin"))


def test_random_weights_and_checkpoint_are_exclusive(tmp_path):
    with pytest.raises(ValueError, match="random_weights"):
        load_encoder("r3m", random_weights=True, checkpoint=str(tmp_path / "x.pt"))


def test_checkpoint_loading_is_weights_only(tmp_path):
    """MAE-style files carrying argparse args load; a pickle that would call a function is refused."""
    import argparse
    import os

    from rdd.encoders._checkpoint import load_state

    ok = tmp_path / "vc1_vitb.pth"
    torch.save({"model": {"cls_token": torch.zeros(1, 1, 4)}, "args": argparse.Namespace(lr=1.0), "epoch": 3}, ok)
    assert load_state(ok, "vc1")["epoch"] == 3

    class Payload:
        def __reduce__(self):
            return (os.getcwd, ())

    bad = tmp_path / "bad.pth"
    torch.save({"model": Payload()}, bad)
    with pytest.raises(ValueError, match="bad.pth"):
        load_state(bad, "vc1")
