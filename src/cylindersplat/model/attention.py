"""Transformer blocks: multi-head self-attention and the VGGT-style alternating stack.

The alternating stack processes tokens ``(B, V, T, D)`` of ``V`` views: even blocks attend within
each view (frame attention), odd blocks over the tokens of all views together (global
attention). Nothing depends on ``V``, so any number of views works with the same weights.
"""

from __future__ import annotations

import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor, nn

from .config import AttentionConfig

__all__ = ["Mlp", "SelfAttention", "TransformerBlock", "AlternatingAttention"]


class Mlp(nn.Sequential):
    def __init__(self, dim: int, hidden: int, out: int | None = None):
        super().__init__(nn.Linear(dim, hidden), nn.GELU(), nn.Linear(hidden, out or dim))


class SelfAttention(nn.Module):
    def __init__(self, dim: int, heads: int):
        super().__init__()
        if dim % heads:
            raise ValueError(f"attention width {dim} must be divisible by the number of heads {heads}")
        self.heads = heads
        self.qkv = nn.Linear(dim, 3 * dim)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: Float[Tensor, "N T D"]) -> Float[Tensor, "N T D"]:
        n, t, d = x.shape
        q, k, v = self.qkv(x).view(n, t, 3, self.heads, d // self.heads).permute(2, 0, 3, 1, 4)
        out = F.scaled_dot_product_attention(q, k, v)
        return self.proj(out.transpose(1, 2).reshape(n, t, d))


class TransformerBlock(nn.Module):
    """Pre-norm block: ``x + attn(norm(x))``, then ``x + mlp(norm(x))``."""

    def __init__(self, dim: int, heads: int, mlp_ratio: float):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim)
        self.attn = SelfAttention(dim, heads)
        self.norm2 = nn.LayerNorm(dim)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))

    def forward(self, x: Tensor) -> Tensor:
        x = x + self.attn(self.norm1(x))
        return x + self.mlp(self.norm2(x))


class AlternatingAttention(nn.Module):
    """``L`` blocks alternating frame (intra-view) and global (cross-view) attention."""

    def __init__(self, cfg: AttentionConfig):
        super().__init__()
        self.blocks = nn.ModuleList(TransformerBlock(cfg.dim, cfg.heads, cfg.mlp_ratio) for _ in range(cfg.depth))
        self.norm = nn.LayerNorm(cfg.dim)

    @staticmethod
    def block_kind(index: int) -> str:
        return "frame" if index % 2 == 0 else "global"

    def forward(self, tokens: Float[Tensor, "B V T D"]) -> list[Float[Tensor, "B V T D"]]:
        """Normalised outputs of every global block (the last one is the final output).

        Like DPT/VGGT, the decoder reads several depths of the stack, not only the last.
        """
        b, v, t, d = tokens.shape
        x = tokens
        outputs = []
        for index, block in enumerate(self.blocks):
            if self.block_kind(index) == "frame":
                x = block(x.reshape(b * v, t, d)).view(b, v, t, d)
            else:
                x = block(x.reshape(b, v * t, d)).view(b, v, t, d)
                outputs.append(self.norm(x))
        if not outputs:  # a stack without global blocks (L = 1)
            outputs.append(self.norm(x))
        return outputs

    def num_outputs(self) -> int:
        return max(1, sum(self.block_kind(i) == "global" for i in range(len(self.blocks))))
