"""Local motion generator: a 1D fully-convolutional encoder–decoder over time.

Scaled-down Generative Tweening G: the input is the dense key format plus the
interpolation baseline and time-to-arrival channels (``pipeline/infer/features.py``), the
output a residual over interpolation for every joint's 6D rotation and the root, plus
four foot-contact logits. Encoder: strided residual layers (k=4, s=2); decoder:
transposed residual layers back to full rate with additive skips from the encoder.
Sequence length must be a multiple of ``2**len(levels)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import torch
from torch import nn

from pipeline.infer.dna_poses import n_dna_channels
from pipeline.infer.features import n_adapter_channels, n_input_channels, n_output_channels
from pipeline.infer.folder import without_retired
from pipeline.networks.dna import DnaEncoder
from pipeline.networks.layers import ResLayer


@dataclass
class GeneratorConfig:
    n_joints: int = 21
    width: int = 160
    levels: tuple[int, ...] = (160, 192, 256, 256, 256)  # channels after each stride-2 layer
    bottleneck_dilations: tuple[int, ...] = (1, 2)
    key_adapter: bool = False  # partial keys as a side input beside the full-key input (features.py)
    dna: int = 0  # width of the motion-DNA encoder (0: none); its vector joins the bottleneck
    delta: bool = False  # see poses relative to the keys, not as they are (relative_to_keys)
    extra: dict = field(default_factory=dict)

    @classmethod
    def saved(cls, saved: dict, where="a checkpoint") -> GeneratorConfig:
        """The config a checkpoint or model.json saved (lists back to tuples), without the
        switches no release runs any more (pipeline.infer.folder.RETIRED; refused where
        set to anything but the one value every shipped model has)."""
        names = {f.name for f in fields(cls)}
        kw = {k: v for k, v in without_retired(saved, where).items() if k in names}
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in kw.items()})

    @property
    def multiple(self) -> int:
        return 2 ** len(self.levels)

    def receptive_field(self) -> int:
        """Frames one output sees: k=4 s=2 layers, then k=3 dilated convs at the bottleneck."""
        rf, jump = 1, 1
        for _ in self.levels:
            rf += 3 * jump
            jump *= 2
        for d in self.bottleneck_dilations:
            rf += 2 * d * jump
        return rf


def relative_to_keys(x: torch.Tensor, n_joints: int) -> torch.Tensor:
    """The pose channels of the features (``pipeline/infer/features.py``) made relative, as
    in the Δ-interpolator's delta mode: the baseline as its change since the window's first
    frame (the first key: windows start on one, and the baseline holds it before), the dense
    key copy as its offset from the baseline. A constant posture offset (a rig set up
    otherwise, another actor's stance) then reaches the network as a small change of these
    differences instead of a pose it never saw; timing and latent channels pass unchanged."""
    c = n_joints * 6 + 3
    base, key, rest = x[:, :c], x[:, c : 2 * c], x[:, 2 * c :]
    return torch.cat([base - base[:, :, :1], key - base, rest], dim=1)


class Generator(nn.Module):
    def __init__(self, cfg: GeneratorConfig):
        super().__init__()
        self.cfg = cfg
        cin, cout = n_input_channels(cfg.n_joints, cfg.key_adapter), n_output_channels(cfg.n_joints)
        self.in_channels = cin  # the features' width, the adapter's side input included
        self.n_side = n_adapter_channels(cfg.n_joints) if cfg.key_adapter else 0
        self.inp = ResLayer(cin - self.n_side, cfg.width, 3, sigma=1.0)
        # The partial-key adapter: two bias-free convolutions around a PReLU, the last one zero
        # at the start. Zero in gives zero out, so fills from full keys never depend on it.
        self.adapter = None
        if cfg.key_adapter:
            self.adapter = nn.Sequential(
                nn.Conv1d(self.n_side, cfg.width, 3, padding=1, bias=False),
                nn.PReLU(cfg.width),
                nn.Conv1d(cfg.width, cfg.width, 3, padding=1, bias=False),
            )
            nn.init.zeros_(self.adapter[2].weight)
        n = len(cfg.levels)
        chans = [cfg.width, *cfg.levels]
        self.down = nn.ModuleList(
            ResLayer(chans[i], chans[i + 1], 4, stride=2, sigma=1.0 / (i + 2)) for i in range(n)
        )
        self.mid = nn.ModuleList(
            ResLayer(chans[-1], chans[-1], 3, sigma=0.5, dilation=d) for d in cfg.bottleneck_dilations
        )
        # Decoder σ falls toward the output, as in the paper's Table 5.
        self.up = nn.ModuleList(
            ResLayer(chans[i + 1], chans[i], 4, stride=2, sigma=1.0 / (2 + 1.5 * (n - i)), transposed=True)
            for i in reversed(range(n))
        )
        self.refine = nn.ModuleList(
            ResLayer(chans[i], chans[i], 3, sigma=1.0 / (3 + 1.5 * (n - i))) for i in reversed(range(n))
        )
        self.dna = DnaEncoder(n_dna_channels(cfg.n_joints), cfg.dna, chans[-1]) if cfg.dna else None
        self.out = nn.Conv1d(cfg.width, cout, 3, padding=1)
        nn.init.zeros_(self.out.weight)  # start as the interpolation baseline
        nn.init.zeros_(self.out.bias)

    def res_layers(self) -> list[ResLayer]:
        return [m for m in self.modules() if isinstance(m, ResLayer)]

    def forward(
        self, x: torch.Tensor, dna: torch.Tensor | None = None, dna_weight: torch.Tensor | None = None
    ) -> torch.Tensor:
        """(B, C, N) features -> (B, C_out, N); with a DNA encoder also (B, C_dna, R) poses and a
        (B, 1) weight per window (0: no DNA)."""
        main = x.shape[1] - self.n_side
        h = self.inp(relative_to_keys(x[:, :main], self.cfg.n_joints) if self.cfg.delta else x[:, :main])
        if self.adapter is not None:
            h = h + self.adapter(x[:, main:])
        skips = []
        for layer in self.down:
            skips.append(h)
            h = layer(h)
        if self.dna is not None and dna is not None:
            h = h + self.dna(dna, dna_weight)
        for layer in self.mid:
            h = layer(h)
        for up, ref in zip(self.up, self.refine, strict=True):
            h = ref(up(h) + skips.pop())
        return self.out(h)
