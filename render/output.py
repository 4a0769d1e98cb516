"""Review media out: numbered frames through OpenImageIO with metadata, a contact sheet, an
H.264 MP4 (yuv420p) through PyAV with raw frames piped in."""

from __future__ import annotations

import os
import struct
import zlib
from fractions import Fraction
from pathlib import Path

import numpy as np

from render.gl import RenderError

PNG_LEVEL = 1  # zlib level of the numbered frames (see ``png_rows``)
# What libpng (OIIO) writes for an sRGB image: the sRGB chunk and the gAMA/cHRM it implies.
_SRGB_CHUNKS = (
    (b"sRGB", b"\x03"),
    (b"gAMA", struct.pack(">I", 45455)),
    (b"cHRM", struct.pack(">8I", 31270, 32900, 64000, 33000, 30000, 60000, 15000, 6000)),
)


_RGBX = np.dtype({"names": ["rgb"], "formats": ["V3"], "offsets": [0], "itemsize": 4})


def png_rows(rgb: np.ndarray) -> np.ndarray:
    """The PNG scanlines of ``rgb`` (h, w, 3 or 4: its RGB) uint8, each after its filter byte
    (0: none): (h, 3w + 1) uint8, a new array (the caller's buffer can be reused at once)."""
    h, w = rgb.shape[:2]
    rows = np.empty((h, 3 * w + 1), np.uint8)
    rows[:, 0] = 0
    if rgb.shape[2] == 4 and rgb.dtype == np.uint8 and rgb.strides[2] == 1:
        # each pixel's first 3 bytes as one 3-byte item: half the time of the uint8 copy
        # (1.1 ms against 2.3 ms at 960x540), which runs on the writer thread with the GIL
        src = rgb.view(_RGBX)[..., 0]["rgb"]
        rows[:, 1:].view("V3")[...] = src
    else:
        rows[:, 1:].reshape(h, w, 3)[...] = rgb[..., :3]
    return rows


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(data, zlib.crc32(kind)))


def write_png(path: str, rows: np.ndarray, meta: dict, level: int = PNG_LEVEL) -> None:
    """Writes ``png_rows`` output as an 8-bit RGB PNG (sRGB chunk, ``meta`` as text), atomically.

    zlib (the standard library's, which lets go of the GIL while it deflates) at ``level`` 1 on
    unfiltered rows: on the bench's review frames 7 ms a frame against 24 ms for OIIO's
    libpng at level 3 (no filter) and 18.5 ms at level 1, the same size as libpng's level 1
    (0.13 MB) and the same pixels. Text is ``tEXt`` (``iTXt`` if it is not Latin-1), as OIIO
    writes it, and reads back through OIIO as the same attributes."""
    h, w1 = rows.shape
    w = (w1 - 1) // 3
    parts = [b"\x89PNG\r\n\x1a\n", _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))]
    parts += [_chunk(k, v) for k, v in _SRGB_CHUNKS]
    for k, v in meta.items():
        if k == "oiio:ColorSpace":
            continue  # the sRGB chunk says it (read back as oiio:ColorSpace)
        key, text = str(k).encode("latin-1"), str(v)
        try:
            parts.append(_chunk(b"tEXt", key + b"\0" + text.encode("latin-1")))
        except UnicodeEncodeError:
            parts.append(_chunk(b"iTXt", key + b"\0\0\0\0\0" + text.encode("utf-8")))
    parts += [_chunk(b"IDAT", zlib.compress(rows, level)), _chunk(b"IEND", b"")]
    write_whole(path, b"".join(parts), "image")


def write_whole(path: str, data: bytes, what: str) -> None:
    """Writes ``data`` to ``path`` whole or not at all (a temporary beside it, then renamed): a
    full disk is a RenderError naming ``path``. OIIO's PNG writer and OTIO's ``write_to_file``
    said nothing when the disk filled, and a truncated contact sheet or an empty timeline was
    the review's output, with exit 0. Not ``pipeline.atomic.write_bytes``: the frame writer's
    threads call this for every frame, and its temporary sets the process's umask to read it."""
    tmp = f"{path}.tmp{os.getpid()}{Path(path).suffix}"
    try:
        with open(tmp, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except OSError as e:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise RenderError(f"{path}: cannot write {what}: {e.strerror or e}") from None


def frame_metadata(shot: str, take, facts: dict, frame: int, colorspace: str) -> dict:
    return {
        "tween:shot": shot,
        "tween:take": "" if take is None else str(take),
        "tween:model": str(facts.get("model", "")),
        "tween:modelHash": str(facts.get("model_hash", "")),
        "tween:frame": int(frame),
        "oiio:ColorSpace": colorspace,
        "Software": "usd-tween review",
    }


def write_frame(path: str, rgb: np.ndarray, meta: dict, exr: bool = False) -> None:
    """Writes ``rgb`` (h, w, 3 or 4) uint8 sRGB as RGB PNG (``write_png``), or as half-float
    linear EXR through OIIO, atomically."""
    import OpenImageIO as oiio

    if not exr:
        write_png(path, png_rows(rgb), meta)  # PNG keeps only text: ints are written as text
        return
    buf = oiio.ImageBuf(np.ascontiguousarray(rgb[..., :3]))
    buf = oiio.ImageBufAlgo.colorconvert(buf, "sRGB", "lin_rec709")
    buf.set_write_format(oiio.HALF)
    for k, v in meta.items():
        buf.specmod().attribute(k, v)  # EXR keeps typed attributes
    tmp = f"{path}.tmp{os.getpid()}{Path(path).suffix}"
    if not buf.write(tmp):  # OpenEXR, unlike OIIO's PNG writer, reports a full disk
        Path(tmp).unlink(missing_ok=True)
        raise RenderError(f"{path}: cannot write image: {buf.geterror()}")
    os.replace(tmp, path)


def contact_sheet(
    thumbs: list[tuple[np.ndarray, str, bool]], path: str, title: str, columns: int = 4
) -> None:
    """Grid of (image, label, is_key) thumbnails with labels burnt in, written through OIIO."""
    import OpenImageIO as oiio

    th, tw = thumbs[0][0].shape[:2]
    rows = (len(thumbs) + columns - 1) // columns
    pad, head = 6, 40
    W, H = columns * tw + (columns + 1) * pad, rows * th + (rows + 1) * pad + head
    sheet = oiio.ImageBuf(oiio.ImageSpec(W, H, 3, oiio.UINT8))
    oiio.ImageBufAlgo.fill(sheet, [0.06, 0.06, 0.07])
    oiio.ImageBufAlgo.render_text(
        sheet, pad, head // 2, title, 20, "DroidSans", [1, 1, 1, 1], "left", "center"
    )
    for n, (img, label, is_key) in enumerate(thumbs):
        r, c = divmod(n, columns)
        x, y = pad + c * (tw + pad), head + pad + r * (th + pad)
        tile = oiio.ImageBuf(np.ascontiguousarray(img))
        oiio.ImageBufAlgo.render_text(
            tile,
            8,
            th - 10,
            label,
            max(14, th // 12),
            "DroidSansMono",
            [1, 0.45, 0.12, 1] if is_key else [1, 1, 1, 1],
            "left",
            "bottom",
            1,
        )
        oiio.ImageBufAlgo.paste(sheet, x, y, 0, 0, tile)
    # Level 3 unfiltered: a third of zlib 6's time. Written as the frames are (write_png), not by
    # OIIO, whose PNG writer reports no error when the disk fills.
    write_png(path, png_rows(sheet.get_pixels(oiio.UINT8)), {"tween:shot": title}, level=3)


def thumbnail(rgb: np.ndarray, factor: int = 2) -> np.ndarray:
    """Box-filtered 1/``factor`` copy (numpy: OIIO's filtered resize costs ~180 ms at 960x540):
    the floor of each block's mean, summed over strided views (a reshape and ``sum(axis=(1, 3))``
    gives the same pixels at 15x the time)."""
    h, w = (rgb.shape[0] // factor) * factor, (rgb.shape[1] // factor) * factor
    src = rgb[:h, :w, :3]
    acc = src[::factor, ::factor].astype(np.uint16)
    for dy in range(factor):
        for dx in range(factor):
            if dy or dx:
                acc += src[dy::factor, dx::factor]
    return (acc // (factor * factor)).astype(np.uint8)


class Movie:
    """H.264 yuv420p MP4 at the shot's frame rate; ``add(rgb)`` pipes one raw frame to libx264."""

    def __init__(
        self,
        path: str,
        size: tuple[int, int],
        fps: float | Fraction,
        comment: str = "",
        preset: str = "ultrafast",
    ):
        import av

        self.path, self.tmp = path, f"{path}.tmp{os.getpid()}.mp4"
        w, h = size
        self.rate = fps if isinstance(fps, Fraction) else Fraction(fps).limit_denominator(1001)
        try:
            self.box = av.open(self.tmp, mode="w", options={"movflags": "faststart"})
            self.stream = self.box.add_stream("libx264", rate=self.rate)
        except Exception as e:  # PyAV raises codec/format errors with the ffmpeg text
            raise RenderError(f"{path}: cannot start the H.264 encoder: {e}") from None
        self.stream.width, self.stream.height = w, h
        self.stream.pix_fmt = "yuv420p"
        # crf 20, ultrafast with CABAC and the deblocking filter put back (tune animation's 1:1):
        # on the 300-frame bench review half the CPU of superfast (1.85 s against 3.6 s, one
        # thread, 3.1 MB against 2.9 MB) at the same fidelity (luma PSNR against the rendered
        # frames 50.0 dB against 49.8 dB: clay and gradients are easy to code; what ultrafast
        # gives up is search effort, not quality at a set crf). Main profile 4:2:0 (CABAC, no
        # 8x8 transform), which every player decodes, with 2 B-frames: ultrafast has none, and
        # tune animation adds two (x264 writes bframes=2; docs/render.md). One thread: the
        # encoder already runs beside the render loop (the review's writer thread), and slice
        # threads cost CPU and bits.
        self.stream.options = {"preset": preset, "crf": "20", "tune": "animation"}
        if preset == "ultrafast":
            self.stream.options = {**self.stream.options, "x264-params": "cabac=1:deblock=1,1"}
        self.stream.codec_context.thread_count = 1
        if comment:
            self.box.metadata["comment"] = comment
        self.n = 0

    def add(self, rgb: np.ndarray) -> None:
        import av

        frame = av.VideoFrame.from_ndarray(rgb, format="rgba" if rgb.shape[2] == 4 else "rgb24")
        frame.pts = self.n
        self.n += 1
        for packet in self.stream.encode(frame):
            self.box.mux(packet)

    def close(self) -> str:
        for packet in self.stream.encode():
            self.box.mux(packet)
        self.box.close()
        os.replace(self.tmp, self.path)
        return self.path

    def abort(self) -> None:
        try:
            self.box.close()
        finally:
            if os.path.exists(self.tmp):
                os.remove(self.tmp)
