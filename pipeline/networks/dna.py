"""Motion DNA encoder (Generative Tweening Table 5, scaled down).

A per-pose MLP (kernel-1 convolutions over the R representative poses) and an average
pool: any number of poses, in any order, gives one vector w. The generator adds a linear
map of w to its bottleneck features; that map starts at zero, so a generator given a DNA
encoder starts exactly as it was.
"""

from __future__ import annotations

import torch
from torch import nn


class DnaEncoder(nn.Module):
    def __init__(self, channels: int, width: int, out: int):
        super().__init__()
        self.net = nn.Sequential(
            nn.Conv1d(channels, width, 1),
            nn.PReLU(width),
            nn.Conv1d(width, width, 1),
            nn.PReLU(width),
        )
        self.proj = nn.Linear(width, out)
        nn.init.zeros_(self.proj.weight)
        nn.init.zeros_(self.proj.bias)

    def forward(self, poses: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
        """(B, C, R) poses, (B, 1) weight (0: no DNA) -> (B, out, 1) bottleneck offset."""
        w = self.net(poses).mean(dim=2)
        return (self.proj(w) * weight)[:, :, None]
