"""Burn-ins drawn with OpenImageIO (ImageBufAlgo.render_text, the wheel's Droid fonts).

Static text (shot, model, take, panel labels) is rendered once into premultiplied RGBA bands;
only the frame / time code text is rendered per frame, and compositing touches the bands only.
"""

from __future__ import annotations

import json
import os

import numpy as np

FONT = "DroidSansMono"
KEY_RGB = (1.0, 0.45, 0.12)


def timecode(frame: int, fps: float) -> str:
    """Non-drop SMPTE-style HH:MM:SS:FF for a frame number at ``fps``."""
    n = max(int(round(fps)), 1)
    f = int(frame)
    sign = "-" if f < 0 else ""
    f = abs(f)
    return f"{sign}{f // (3600 * n):02d}:{f // (60 * n) % 60:02d}:{f // n % 60:02d}:{f % n:02d}"


def _text_band(w: int, h: int, items, size: int, fill_alpha: float) -> np.ndarray:
    """(h, w, 4) premultiplied float32: a translucent band with (x, y, text, rgb, align) items."""
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(oiio.ImageSpec(w, h, 4, oiio.FLOAT))
    oiio.ImageBufAlgo.fill(buf, [0.0, 0.0, 0.0, fill_alpha])
    for x, y, text, rgb, align in items:
        if text:
            oiio.ImageBufAlgo.render_text(buf, int(x), int(y), text, size, FONT, [*rgb, 1.0], align, "center")
    return buf.get_pixels(oiio.FLOAT).reshape(h, w, 4)


class _Fixed:
    """A premultiplied float RGBA layer as 8.8 fixed point: ``rgb`` (colour*256*255) and ``inv``
    (256*(1-alpha)) for RGB destinations, and the same spread over 4 channels with the
    rounding folded in (``add4``: colour + 128, alpha channel 0; ``inv4``: alpha channel 256,
    which keeps the destination's alpha) for RGBA ones, made when first needed."""

    def __init__(self, src: np.ndarray):
        self.rgb = np.round(np.clip(src[..., :3], 0, 1) * 255 * 256).astype(np.uint16)
        self.inv = np.round((1.0 - np.clip(src[..., 3:4], 0, 1)) * 256).astype(np.uint16)
        self._rgba = None

    def crop(self, h: int, w: int) -> _Fixed:
        """The top-left ``h`` × ``w`` of the layer (what fits where the frame ends)."""
        out = object.__new__(_Fixed)
        out.rgb, out.inv, out._rgba = self.rgb[:h, :w], self.inv[:h, :w], None
        return out

    def rgba(self) -> tuple[np.ndarray, np.ndarray]:
        if self._rgba is None:
            h, w = self.rgb.shape[:2]
            add4 = np.zeros((h, w, 4), np.uint16)
            add4[..., :3] = self.rgb + 128
            inv4 = np.full((h, w, 4), 256, np.uint16)
            inv4[..., :3] = self.inv
            self._rgba = add4, inv4
        return self._rgba


def _over(dst: np.ndarray, src) -> None:
    """In place: premultiplied ``src`` (float RGBA, or ``_Fixed`` of it) over ``dst`` (uint8 RGB,
    or RGBA whose alpha is kept).

    Static layers are pre-converted to fixed point, so a frame's burn-in is a few integer ops;
    on RGBA rows (the GL read-back, contiguous) they run on whole pixels without a strided
    view, with the same result on the colour: (dst * inv + rgb + 128) >> 8.
    """
    layer = _Fixed(src) if isinstance(src, np.ndarray) else src
    if layer.rgb.shape[:2] != dst.shape[:2]:  # a frame smaller than the burn-in (--size 32x16)
        layer = layer.crop(*dst.shape[:2])
    if dst.shape[-1] == 4:
        add4, inv4 = layer.rgba()
        acc = np.multiply(dst, inv4, dtype=np.uint16)
        acc += add4
        acc >>= 8
        np.copyto(dst, acc, casting="unsafe")
        return
    dst[...] = ((dst * layer.inv + layer.rgb + 128) >> 8).astype(np.uint8)


def decided_label(facts: dict) -> str:
    """What to call the network that filled a character: "model" for its own, else (a network
    shipped beside it that the probes chose, ``tween:trustEvidence``'s ``source``) that one's
    name after the prefix the two names share ("delta-v2" for tween-bandai-delta-v2 beside
    tween-bandai-v5.3; "model" where they share none: the network beside a studio library)."""
    try:
        source = json.loads(facts.get("trust_evidence") or "{}").get("source")
    except (ValueError, AttributeError):  # evidence of another shape: say no more than before
        return "model"
    own = str(facts.get("model") or "")
    if not isinstance(source, str) or source == own:
        return "model"
    shared = os.path.commonprefix([source, own])
    return source[len(shared) :] if shared and len(shared) < len(source) else "model"


def fill_sources(facts: dict) -> list[tuple[float, float, str]]:
    """(from, to, label) per gap the trusted fill decided on: a motion library's gaps
    (``tween:libraryGaps`` / ``tween:libraryShare``: "library", "spline", "library NN%"),
    else the network's (``tween:trustGaps`` / ``tween:trustGapWeights``: "model", "spline",
    "model NN%"; a network shipped beside it by its :func:`decided_label`)."""
    for name, gaps, share in (
        ("library", "library_gaps", "library_share"),
        (decided_label(facts), "trust_gaps", "trust_gap_weights"),
    ):
        g, w = facts.get(gaps), facts.get(share)
        if g is None or w is None or len(g) != len(w) or not len(g):
            continue
        out = []
        for (a, b), s in zip(g, w, strict=True):
            s = float(s)
            label = name if s >= 0.995 else "spline" if s <= 0.005 else f"{name} {100 * s:.0f}%"
            out.append((float(a), float(b), label))
        return out
    return []


def source_at(sources: list[tuple[float, float, str]], t: float) -> str | None:
    """The label of the gap time code ``t`` lies in (None outside every gap)."""
    for a, b, label in sources:
        if a < t < b:
            return label
    return None


class BurnIn:
    """Burn-ins for frames of ``size``: shot / model / take / frame + time code / KEY."""

    def __init__(self, size, shot: str, facts: dict, fps: float, panel_labels: list[str] | None = None):
        self.w, self.h = size
        self.fps = fps
        self.font = max(9, round(min(self.h * 0.03, self.w * 0.018)))
        self.band = round(self.font * 1.7)
        mid = self.band // 2
        model = facts.get("model")
        mhash = str(facts.get("model_hash", ""))[:12]
        right = f"model {model} {mhash}".strip() if model else "no model (plain shot)"
        take = facts.get("take")
        take_txt = f"take {take}" if take is not None else "take -"
        if facts.get("seed") is not None:
            take_txt += f"   seed {facts['seed']}"
        pad = self.font // 2
        top = [(pad, mid, shot, (1, 1, 1), "left"), (self.w - pad, mid, right, (0.85, 0.9, 1.0), "right")]
        if panel_labels:
            pw = self.w // len(panel_labels)
            top_labels = [
                (pw * k + pw // 2, mid, lab, (0.8, 0.8, 0.8), "center") for k, lab in enumerate(panel_labels)
            ]
            self.labels = _text_band(self.w, self.band, top_labels, self.font, 0.0)
        else:
            self.labels = None
        self.top = _text_band(self.w, self.band, top, self.font, 0.55)
        self.bottom = _text_band(
            self.w, self.band, [(pad, mid, take_txt, (1, 1, 1), "left")], self.font, 0.55
        )
        kw = self.font * 4
        self.key_rect = (self.w // 2 - kw // 2, 2, kw, self.band - 4)  # x, y, w, h
        self.key_badge = _text_band(
            kw,
            self.band - 4,
            [(kw // 2, (self.band - 4) // 2, "KEY", (0, 0, 0), "center")],
            round(self.font * 1.1),
            0.0,
        )
        self.key_badge[..., :3] += np.array(KEY_RGB, np.float32) * (1.0 - self.key_badge[..., 3:4])
        self.key_badge[..., 3] = 1.0
        self.frame_w = min(self.font * 16, self.w)
        self.sources = fill_sources(facts)
        self.source_w = min(self.font * 12, self.w // 3)
        self.top, self.bottom, self.key_badge = _Fixed(self.top), _Fixed(self.bottom), _Fixed(self.key_badge)
        if self.labels is not None:
            self.labels = _Fixed(self.labels)

    def apply(self, img: np.ndarray, frame: int, is_key: bool, tc: str | None = None) -> None:
        """Burns the text into ``img`` (h, w, 3) uint8 in place (or (h, w, 4), alpha kept); ``tc`` is the frame's time code
        (``scene.timecodes``; default: ``frame`` counted at the burn-in's fps)."""
        b, w = self.band, self.w
        _over(img[:b], self.top)
        _over(img[-b:], self.bottom)
        if self.labels is not None:
            _over(img[b : 2 * b], self.labels)
            x = self.w // 2
            img[b:-b, x - 1 : x + 1, :3] = 150  # the seam between the panels
        rgb = KEY_RGB if is_key else (1, 1, 1)
        text = f"{frame:>6d}   {tc if tc is not None else timecode(frame, self.fps)}"
        strip = _text_band(
            self.frame_w, b, [(self.frame_w - self.font // 2, b // 2, text, rgb, "right")], self.font, 0.0
        )
        _over(img[-b:, w - self.frame_w :], strip)
        label = None if is_key else source_at(self.sources, frame)
        if label:  # what filled this frame: the library's takes, the spline, or a blend of both
            x0 = (w - self.source_w) // 2
            strip = _text_band(self.source_w, b, [(self.source_w // 2, b // 2, label, (0.85, 0.9, 1.0), "center")],
                               self.font, 0.0)  # fmt: skip
            _over(img[-b:, x0 : x0 + self.source_w], strip)
        if is_key:
            x, y, kw, kh = self.key_rect
            _over(img[y : y + kh, x : x + kw], self.key_badge)
            t = max(2, self.h // 135)  # a border that reads at thumbnail size
            k = np.array([round(c * 255) for c in KEY_RGB], np.uint8)
            rgb3 = img[..., :3]
            rgb3[:t], rgb3[-t:], rgb3[:, :t], rgb3[:, -t:] = k, k, k, k
