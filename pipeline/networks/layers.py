"""The modified residual layer of Generative Tweening (eq. 6), read as intended:

    y = sqrt(σ) · PReLU(affine(conv(x))) + sqrt(1 − σ) · skip(x)

σ decreases toward the output so later layers pass more of their input through. When the
layer changes length or width, the skip resamples in time (average pooling for stride 2,
nearest repeat for the transposed form) and projects channels with a 1×1 convolution (the
paper leaves this open). The conv outputs are kept for the batch-regularisation loss (eq. 9).
"""

from __future__ import annotations

import math

import torch
from torch import nn


class Affine(nn.Module):
    def __init__(self, ch: int):
        super().__init__()
        self.scale = nn.Parameter(torch.ones(1, ch, 1))
        self.bias = nn.Parameter(torch.zeros(1, ch, 1))

    def forward(self, x):
        return x * self.scale + self.bias


class ResLayer(nn.Module):
    def __init__(
        self,
        cin: int,
        cout: int,
        k: int,
        stride: int = 1,
        sigma: float = 1.0,
        transposed: bool = False,
        dilation: int = 1,
    ):
        super().__init__()
        self.sigma, self.stride, self.transposed = sigma, stride, transposed
        if transposed:
            self.conv = nn.ConvTranspose1d(cin, cout, k, stride=stride, padding=(k - stride) // 2)
        else:
            pad = dilation * (k - 1) // 2 if stride == 1 else (k - stride) // 2
            self.conv = nn.Conv1d(cin, cout, k, stride=stride, padding=pad, dilation=dilation)
        self.affine = Affine(cout)
        self.act = nn.PReLU(cout)
        self.proj = nn.Conv1d(cin, cout, 1) if (sigma < 1 and cin != cout) else None
        self.last_conv_out: torch.Tensor | None = None

    def forward(self, x):
        h = self.conv(x)
        self.last_conv_out = h
        y = self.act(self.affine(h))
        if self.sigma >= 1:
            return y
        s = x
        if self.stride > 1:
            s = (
                torch.repeat_interleave(s, self.stride, dim=-1)
                if self.transposed
                else nn.functional.avg_pool1d(s, self.stride)
            )
        if self.proj is not None:
            s = self.proj(s)
        return math.sqrt(self.sigma) * y + math.sqrt(1 - self.sigma) * s


def batch_regularisation(layers: list[ResLayer]) -> torch.Tensor:
    """Eq. 9: push each conv feature's batch×time mean to 0 and std to 1."""
    terms = []
    for layer in layers:
        h = layer.last_conv_out
        if h is None:
            continue
        mean = h.mean(dim=(0, 2))
        std = h.std(dim=(0, 2)) + 1e-5
        terms.append((mean.square() + torch.log(std).square()).mean())
    return torch.stack(terms).mean() if terms else torch.zeros(())
