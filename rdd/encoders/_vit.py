"""Vision Transformer in plain torch with timm/DINOv2 module names (``blocks.N.attn.qkv`` ...).

One class serves VC-1 (MAE ViT-B/16, fixed 224x224 positions, CLS token after the final norm) and
DINOv2 (ViT-L/14 with LayerScale, positions for 518x518 interpolated bicubically to the input grid
with DINOv2's 0.1 offset, CLS token after the final norm).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


class PatchEmbed(nn.Module):
    """Non-overlapping patches -> tokens with one strided convolution (``patch_embed.proj``)."""

    def __init__(self, patch_size: int, embed_dim: int):
        super().__init__()
        self.patch_size = patch_size
        self.proj = nn.Conv2d(3, embed_dim, kernel_size=patch_size, stride=patch_size)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3, H, W) -> (N, H/p * W/p, D)."""
        return self.proj(x).flatten(2).transpose(1, 2)


class Attention(nn.Module):
    """Multi-head self-attention with a fused qkv projection."""

    def __init__(self, dim: int, num_heads: int):
        super().__init__()
        self.num_heads = num_heads
        self.qkv = nn.Linear(dim, dim * 3, bias=True)
        self.proj = nn.Linear(dim, dim, bias=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, L, D) -> (N, L, D)."""
        n, length, dim = x.shape
        qkv = self.qkv(x).reshape(n, length, 3, self.num_heads, dim // self.num_heads).permute(2, 0, 3, 1, 4)
        y = F.scaled_dot_product_attention(qkv[0], qkv[1], qkv[2])
        return self.proj(y.transpose(1, 2).reshape(n, length, dim))


class Mlp(nn.Module):
    """fc1 -> exact GELU -> fc2."""

    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.act = nn.GELU()
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Position-wise feed-forward."""
        return self.fc2(self.act(self.fc1(x)))


class LayerScale(nn.Module):
    """Per-channel learned scale (DINOv2's ``ls1``/``ls2`` with parameter ``gamma``)."""

    def __init__(self, dim: int, init_values: float = 1e-5):
        super().__init__()
        self.gamma = nn.Parameter(torch.full((dim,), float(init_values)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x * gamma."""
        return x * self.gamma


class Block(nn.Module):
    """Pre-norm transformer block, optionally with LayerScale."""

    def __init__(self, dim: int, num_heads: int, mlp_ratio: float, layerscale: bool):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=1e-6)
        self.attn = Attention(dim, num_heads)
        self.ls1 = LayerScale(dim) if layerscale else nn.Identity()
        self.norm2 = nn.LayerNorm(dim, eps=1e-6)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))
        self.ls2 = LayerScale(dim) if layerscale else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x + attn, then x + mlp."""
        x = x + self.ls1(self.attn(self.norm1(x)))
        return x + self.ls2(self.mlp(self.norm2(x)))


class VisionTransformer(nn.Module):
    """ViT returning the final-normed CLS token.

    ``pos_interp``: "none" (input grid must equal the trained grid, as VC-1/timm) or "dinov2"
    (bicubic interpolation with DINOv2's ``interpolate_offset=0.1``, no antialiasing).
    """

    def __init__(self, *, img_size: int, patch_size: int, embed_dim: int, depth: int, num_heads: int,
                 mlp_ratio: float = 4.0, layerscale: bool = False, mask_token: bool = False,
                 pos_interp: str = "none"):
        super().__init__()
        if pos_interp not in ("none", "dinov2"):
            raise ValueError(f"pos_interp must be 'none' or 'dinov2', got {pos_interp!r}")
        self.patch_size = patch_size
        self.grid = img_size // patch_size
        self.pos_interp = pos_interp
        self.patch_embed = PatchEmbed(patch_size, embed_dim)
        self.cls_token = nn.Parameter(torch.zeros(1, 1, embed_dim))
        self.pos_embed = nn.Parameter(torch.randn(1, self.grid**2 + 1, embed_dim) * 0.02)
        self.blocks = nn.ModuleList(Block(embed_dim, num_heads, mlp_ratio, layerscale) for _ in range(depth))
        self.norm = nn.LayerNorm(embed_dim, eps=1e-6)
        if mask_token:
            # Unused at inference; present because DINOv2's checkpoints carry it.
            self.mask_token = nn.Parameter(torch.zeros(1, embed_dim))

    def _positions(self, rows: int, cols: int) -> torch.Tensor:
        """Position embeddings (1, 1 + rows*cols, D) for a rows x cols patch grid."""
        if rows == self.grid and cols == self.grid:
            return self.pos_embed
        if self.pos_interp == "none":
            raise ValueError(
                f"this ViT was trained on a {self.grid}x{self.grid} patch grid; got {rows}x{cols} "
                f"(resize inputs to {self.grid * self.patch_size}x{self.grid * self.patch_size})"
            )
        pos = self.pos_embed.float()
        cls_pos, patch_pos = pos[:, :1], pos[:, 1:]
        m, dim = self.grid, pos.shape[-1]
        # DINOv2's interpolate_pos_encoding: scale factors (n + 0.1) / M, bicubic, no antialiasing.
        patch_pos = F.interpolate(
            patch_pos.reshape(1, m, m, dim).permute(0, 3, 1, 2),
            scale_factor=((rows + 0.1) / m, (cols + 0.1) / m),
            mode="bicubic",
            antialias=False,
        )
        if tuple(patch_pos.shape[-2:]) != (rows, cols):
            raise RuntimeError(f"position interpolation gave {tuple(patch_pos.shape[-2:])}, wanted {(rows, cols)}")
        patch_pos = patch_pos.permute(0, 2, 3, 1).reshape(1, -1, dim)
        return torch.cat([cls_pos, patch_pos], dim=1).to(self.pos_embed.dtype)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3, H, W) normalised images -> (N, D) CLS features after the final LayerNorm."""
        rows, cols = x.shape[-2] // self.patch_size, x.shape[-1] // self.patch_size
        tokens = self.patch_embed(x)
        tokens = torch.cat([self.cls_token.expand(tokens.shape[0], -1, -1), tokens], dim=1)
        tokens = tokens + self._positions(rows, cols)
        for block in self.blocks:
            tokens = block(tokens)
        return self.norm(tokens)[:, 0]
