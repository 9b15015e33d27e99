"""The plain-torch architectures against independent implementations (transformers' model classes).

Weights are random; the test maps them into transformers' layout and compares outputs, so a wrong
residual, norm, attention split, stride placement or output token would show up as a mismatch.
"""

import pytest
import torch

transformers = pytest.importorskip("transformers", reason="transformers is the independent reference")

from rdd.encoders._resnet import ResNet50  # noqa: E402
from rdd.encoders._vit import VisionTransformer  # noqa: E402


def _vit_to_hf(sd: dict, layer_prefix: str, dinov2: bool) -> dict:
    out = {
        "embeddings.cls_token": sd["cls_token"],
        "embeddings.position_embeddings": sd["pos_embed"],
        "embeddings.patch_embeddings.projection.weight": sd["patch_embed.proj.weight"],
        "embeddings.patch_embeddings.projection.bias": sd["patch_embed.proj.bias"],
        "layernorm.weight": sd["norm.weight"],
        "layernorm.bias": sd["norm.bias"],
    }
    if dinov2:
        out["embeddings.mask_token"] = sd["mask_token"]
    depth = len({k.split(".")[1] for k in sd if k.startswith("blocks.")})
    for i in range(depth):
        b, h = f"blocks.{i}.", f"{layer_prefix}{i}."
        for part, name in (("weight", "weight"), ("bias", "bias")):
            q, k, v = sd[b + f"attn.qkv.{part}"].chunk(3, dim=0)
            out[h + f"attention.q_proj.{name}"] = q
            out[h + f"attention.k_proj.{name}"] = k
            out[h + f"attention.v_proj.{name}"] = v
            out[h + f"attention.o_proj.{name}"] = sd[b + f"attn.proj.{part}"]
            out[h + f"mlp.fc1.{name}"] = sd[b + f"mlp.fc1.{part}"]
            out[h + f"mlp.fc2.{name}"] = sd[b + f"mlp.fc2.{part}"]
            n1, n2 = ("norm1", "norm2") if dinov2 else ("layernorm_before", "layernorm_after")
            out[h + f"{n1}.{name}"] = sd[b + f"norm1.{part}"]
            out[h + f"{n2}.{name}"] = sd[b + f"norm2.{part}"]
        if dinov2:
            out[h + "layer_scale1.lambda1"] = sd[b + "ls1.gamma"]
            out[h + "layer_scale2.lambda1"] = sd[b + "ls2.gamma"]
    return out


def _randomise_norms(model: torch.nn.Module) -> None:
    """Non-trivial norm parameters and statistics, so a misplaced norm cannot hide."""
    g = torch.Generator().manual_seed(3)
    for m in model.modules():
        if isinstance(m, (torch.nn.LayerNorm, torch.nn.BatchNorm2d)):
            m.weight.data = 1 + 0.2 * torch.randn(m.weight.shape, generator=g)
            m.bias.data = 0.2 * torch.randn(m.bias.shape, generator=g)
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean = 0.1 * torch.randn(m.running_mean.shape, generator=g)
            m.running_var = 0.5 + torch.rand(m.running_var.shape, generator=g)


def test_vc1_style_vit_matches_transformers_vit():
    torch.manual_seed(0)
    ours = VisionTransformer(img_size=48, patch_size=16, embed_dim=64, depth=2, num_heads=4).eval()
    _randomise_norms(ours)
    cfg = transformers.ViTConfig(hidden_size=64, num_hidden_layers=2, num_attention_heads=4, intermediate_size=256,
                                 image_size=48, patch_size=16, layer_norm_eps=1e-6, hidden_act="gelu", qkv_bias=True)
    ref = transformers.ViTModel(cfg, add_pooling_layer=False).eval()
    ref.load_state_dict(_vit_to_hf(ours.state_dict(), "layers.", dinov2=False), strict=True)
    x = torch.randn(2, 3, 48, 48)
    with torch.inference_mode():
        expected = ref(pixel_values=x).last_hidden_state[:, 0]
        torch.testing.assert_close(ours(x), expected, rtol=1e-4, atol=1e-4)


def test_dinov2_style_vit_matches_transformers_dinov2():
    torch.manual_seed(0)
    ours = VisionTransformer(img_size=56, patch_size=14, embed_dim=64, depth=2, num_heads=4,
                             layerscale=True, mask_token=True, pos_interp="dinov2").eval()
    _randomise_norms(ours)
    for blk in ours.blocks:
        blk.ls1.gamma.data = torch.rand(64) + 0.5
        blk.ls2.gamma.data = torch.rand(64) + 0.5
    cfg = transformers.Dinov2Config(hidden_size=64, num_hidden_layers=2, num_attention_heads=4, mlp_ratio=4,
                                    image_size=56, patch_size=14, layer_norm_eps=1e-6, layerscale_value=1.0)
    ref = transformers.Dinov2Model(cfg).eval()
    ref.load_state_dict(_vit_to_hf(ours.state_dict(), "encoder.layer.", dinov2=True), strict=True)
    x = torch.randn(2, 3, 56, 56)
    with torch.inference_mode():
        torch.testing.assert_close(ours(x), ref(pixel_values=x).pooler_output, rtol=1e-4, atol=1e-4)
        # A smaller grid goes through position interpolation: same size, finite, and not the native path.
        small = ours(torch.randn(1, 3, 42, 42))
    assert small.shape == (1, 64) and torch.isfinite(small).all()


def _resnet_to_hf(sd: dict) -> dict:
    def bn(dst, src):
        return {f"{dst}.normalization.{p}": sd[f"{src}.{p}"]
                for p in ("weight", "bias", "running_mean", "running_var", "num_batches_tracked")}

    out = {"resnet.embedder.embedder.convolution.weight": sd["conv1.weight"], **bn("resnet.embedder.embedder", "bn1"),
           "classifier.1.weight": sd["fc.weight"], "classifier.1.bias": sd["fc.bias"]}
    for s, n in enumerate((3, 4, 6, 3)):
        for j in range(n):
            ours, hf = f"layer{s + 1}.{j}", f"resnet.encoder.stages.{s}.layers.{j}"
            for k in range(3):
                out[f"{hf}.layer.{k}.convolution.weight"] = sd[f"{ours}.conv{k + 1}.weight"]
                out.update(bn(f"{hf}.layer.{k}", f"{ours}.bn{k + 1}"))
            if j == 0:
                out[f"{hf}.shortcut.convolution.weight"] = sd[f"{ours}.downsample.0.weight"]
                out.update(bn(f"{hf}.shortcut", f"{ours}.downsample.1"))
    return out


def test_resnet50_matches_transformers_resnet():
    torch.manual_seed(0)
    ours = ResNet50(fc_out=1000).eval()
    _randomise_norms(ours)
    cfg = transformers.ResNetConfig(embedding_size=64, hidden_sizes=[256, 512, 1024, 2048], depths=[3, 4, 6, 3],
                                    layer_type="bottleneck", hidden_act="relu", downsample_in_first_stage=False,
                                    downsample_in_bottleneck=False, num_labels=1000)
    ref = transformers.ResNetForImageClassification(cfg).eval()
    ref.load_state_dict(_resnet_to_hf(ours.state_dict()), strict=True)
    x = torch.randn(1, 3, 64, 64)
    with torch.inference_mode():
        torch.testing.assert_close(ours(x), ref(pixel_values=x).logits, rtol=1e-3, atol=1e-3)


def test_clip_attention_pool_matches_explicit_attention():
    """CLIP's attention pool written out by hand: the mean token queries all tokens, per head."""
    from rdd.encoders._clip_resnet import AttentionPool2d

    torch.manual_seed(0)
    heads, dim, out_dim, side = 4, 32, 24, 3
    pool = AttentionPool2d(side, dim, heads, out_dim).eval()
    x = torch.randn(2, dim, side, side)
    tokens = x.flatten(2).transpose(1, 2)  # (N, hw, C)
    tokens = torch.cat([tokens.mean(1, keepdim=True), tokens], 1) + pool.positional_embedding
    q = pool.q_proj(tokens[:, :1]).view(2, 1, heads, dim // heads).transpose(1, 2)
    k = pool.k_proj(tokens).view(2, -1, heads, dim // heads).transpose(1, 2)
    v = pool.v_proj(tokens).view(2, -1, heads, dim // heads).transpose(1, 2)
    att = torch.softmax(q @ k.transpose(-1, -2) / (dim // heads) ** 0.5, dim=-1)
    expected = pool.c_proj((att @ v).transpose(1, 2).reshape(2, dim))
    with torch.inference_mode():
        torch.testing.assert_close(pool(x), expected, rtol=1e-5, atol=1e-5)
