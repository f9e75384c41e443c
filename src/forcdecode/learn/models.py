"""The seed paper's CNN and a smaller laptop head (PyTorch).

Input: a 64×64 FORC image (uint8, scaled to [0, 1]) and the normalized M_s. ``PaperCNN``: conv
1→8 (3×3, 64→62), conv 8→16 (3×3, →60), flatten 57,600, concatenated with 625 nodes each carrying
the normalized M_s (58,225), dense → 4,096 → 11; ReLU. Dropout (p = 0.5) sits where the paper and its
authors' public code put it: after the second convolution and after the first dense layer; none on
the first convolution, and the M_s nodes are never dropped (the conv features are dropped once,
before they are joined with M_s). ``SmallCNN``: the same convolutions, a 4×4 average pool (16·15·15 = 3,600 features)
before the dense block, dense → ``width`` → 11. Both accept other image sides (the CI configuration
uses 16×16 images); the paper's counts hold for 64.
"""

from __future__ import annotations

import torch
from torch import nn

MS_NODES = 625


def conv_features(image_size: int, pooled: bool) -> int:
    """Flattened feature count after the two valid 3×3 convolutions (and the 4×4 pool)."""
    side = image_size - 4
    if pooled:
        side //= 4
    if side < 1:
        raise ValueError(f"image side {image_size} is too small for the network (needs >= {8 if pooled else 5})")
    return 16 * side * side


class _Base(nn.Module):
    def __init__(self, pooled: bool, width: int, dropout: float = 0.5, image_size: int = 64):
        super().__init__()
        self.image_size = image_size
        self.conv1 = nn.Conv2d(1, 8, 3)
        self.conv2 = nn.Conv2d(8, 16, 3)
        self.pool = nn.AvgPool2d(4) if pooled else nn.Identity()
        features = conv_features(image_size, pooled)
        self.drop_conv = nn.Dropout(dropout)
        self.dense1 = nn.Linear(features + MS_NODES, width)
        self.drop_hidden = nn.Dropout(dropout)
        self.dense2 = nn.Linear(width, 11)
        # float32 whatever torch's default dtype is (importing magnum.np switches it to float64)
        self.float()

    def forward(self, image: torch.Tensor, ms_norm: torch.Tensor) -> torch.Tensor:
        """``image``: (n, 64, 64) or (n, 1, 64, 64) in [0, 1]; ``ms_norm``: (n,)."""
        image = image.to(torch.float32)
        ms_norm = ms_norm.to(torch.float32)
        x = image.unsqueeze(1) if image.dim() == 3 else image
        x = torch.relu(self.conv1(x))
        x = self.drop_conv(torch.relu(self.conv2(x)))
        x = self.pool(x).flatten(1)
        ms = ms_norm.reshape(-1, 1).expand(-1, MS_NODES)
        x = torch.cat([x, ms], dim=1)
        x = self.drop_hidden(torch.relu(self.dense1(x)))
        return self.dense2(x)


class PaperCNN(_Base):
    def __init__(self, dropout: float = 0.5, image_size: int = 64):
        super().__init__(pooled=False, width=4096, dropout=dropout, image_size=image_size)


class SmallCNN(_Base):
    def __init__(self, width: int = 256, dropout: float = 0.5, image_size: int = 64):
        super().__init__(pooled=True, width=width, dropout=dropout, image_size=image_size)


def build_network(model: str, width: int = 256, image_size: int = 64, dropout: float = 0.5) -> nn.Module:
    """``paper`` (the seed paper's exact network) or ``small`` (pooled laptop head of ``width``)."""
    if model == "paper":
        return PaperCNN(dropout=dropout, image_size=image_size)
    if model == "small":
        return SmallCNN(width=width, dropout=dropout, image_size=image_size)
    raise ValueError(f"unknown network {model!r} (expected 'paper' or 'small')")


def image_tensor(images_uint8) -> torch.Tensor:
    """uint8 images → float32 tensor in [0, 1]."""
    return torch.as_tensor(images_uint8, dtype=torch.float32) / 255.0
