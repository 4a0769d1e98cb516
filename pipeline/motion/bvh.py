"""BVH reading and writing (``.bvh`` and ``.bvh.gz``).

Written here because no maintained PyPI package reads BVH with per-source root rules and
line-numbered errors. Rotations are intrinsic in channel order (``Zrotation Xrotation
Yrotation`` means R = Rz·Rx·Ry, scipy's ``from_euler("ZXY")``).

The root's position channels need a per-source rule (``root_position``; by default told from
the take itself, :func:`_root_rule`):

- ``"replace"``: the channels are the joint's translation and its OFFSET is ignored
  (Bandai Namco; its Hips OFFSET differs per clip and is meaningless).
- ``"add"``: the channels are added to the OFFSET (the CMU/iClone rig; read as a
  replacement its feet end up about 96 cm below the ground).

Position channels below the root replace the OFFSET with their first frame (in Bandai they
equal it). Any channel order and any subset of the six channels per joint is read. Files
that are not UTF-8 are read as Latin-1; joint names are kept as written
(``pipeline.usd.convert`` makes USD names of them).
"""

from __future__ import annotations

import gzip
import re
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.errors import MotionFormatError
from pipeline.inputs import not_a_file
from pipeline.motion.clip import Motion
from pipeline.motion.rotations import euler_to_quat, quat_apply, quat_mul, quat_to_euler
from pipeline.motion.skeleton import Skeleton

ROOT_POSITION_RULES = ("replace", "add")
_VALID_CHANNELS = {"Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation"}


def _root_rule(joints: list[BvhJoint], data: np.ndarray) -> str:
    """The root rule a file's content (its channel values ``data``) asks for: "add" where
    adding the root's OFFSET to its position channels brings the take's lowest point (every
    joint, a frame in up to 200) nearer the ground than reading them as replacements, as for
    the CMU/iClone rig (about 96 cm below the ground otherwise, whatever the file is called);
    else "replace". Told by content, so a copied or renamed take reads the same."""
    root = joints[0]
    lift = root.offset[1] if "Yposition" in root.channels else 0.0
    if not lift:
        return "replace"  # both rules read the same heights
    t, r = _joint_transforms(joints, data[:: max(1, len(data) // 200)], "replace")
    pos = np.empty(t.shape)
    world = np.empty(r.shape)
    with np.errstate(all="ignore"):  # values too large for the model are refused after, in one line
        for j, jt in enumerate(joints):  # file order: a parent comes before its children
            if jt.parent < 0:
                pos[:, j], world[:, j] = t[:, j], r[:, j]
            else:
                pos[:, j] = pos[:, jt.parent] + quat_apply(world[:, jt.parent], t[:, j])
                world[:, j] = quat_mul(world[:, jt.parent], r[:, j])
        low = float(pos[..., 1].min())  # the root's translation moves every joint with it
        return "add" if abs(low + lift) < abs(low) else "replace"


@dataclass
class BvhJoint:
    name: str
    parent: int
    offset: np.ndarray
    channels: list[str]
    end_site: np.ndarray | None = None


#: The most text (bytes, after gzip) a BVH take may hold: 10 hours of a 100-joint rig at
#: 30 fps is about 0.4 GiB.
MAX_BYTES = 1 << 30
#: The largest magnitude of any number in a take (an OFFSET, a position or an angle): 10 km in
#: centimetres, and 2,700 turns in degrees. Beyond it nothing is motion capture, and squares
#: and products of such values overflow into NaN in every step after reading (the mesh, FK).
MAX_VALUE = 1e6
#: The most frames a take may declare (``Frames:``): shots' limit (``pipeline.usd.keys``),
#: 9 hours at 30 fps. Checked before the frames are read: a small gzip declaring 5,000,000
#: frames of a short line took minutes and GiBs, then made a 46-hour clip.
MAX_FRAMES = 1_000_000
#: The most joints a take's hierarchy may hold, and how deep it may nest them (the root is
#: level 1). Far above any rig here (the CMU/iClone rig has 101 joints, 13 deep; Bandai 21)
#: and a film rig's thousands; the joint count is ``pipeline.rig.source``'s for clips. USD
#: joint tokens are full paths, so a chain of N joints holds N²/2 names: 20,000 nested joints
#: in a 1 MB BVH took `tween convert` 5.3 GB and wrote a 576 MB shot.
MAX_JOINTS = 10_000
MAX_DEPTH = 256
#: The most lines a BVH file may have: a take's frames, and a hierarchy of up to a million
#: lines (ten thousand joints take a tenth of it).
MAX_LINES = 2 * MAX_FRAMES
#: How much of a file's text :func:`_open_text` reads at a time (bytes).
_READ_CHUNK = 1 << 24


def is_bvh(path: str | Path) -> bool:
    """Whether a file is a BVH take by its name, in any case (``WALK.BVH``, ``.bvh.gz``)."""
    return Path(path).name.lower().endswith((".bvh", ".bvh.gz"))


def gzipped(path: str | Path) -> bool:
    """Whether a file is gzip data, by its first bytes (not its name: ``.BVH.GZ``, a gzipped
    ``.bvh``)."""
    with open(path, "rb") as f:
        return f.read(2) == b"\x1f\x8b"


def _open_text(path: Path) -> list[str]:
    """The file's lines. UTF-8 (with or without a BOM); a file that is not UTF-8 is read as
    Latin-1, so joint names written by older tools keep their accented letters."""
    try:
        if why := not_a_file(path, "BVH file"):  # a FIFO or a device would block or never end
            raise MotionFormatError(path, None, why)
        zipped = gzipped(path)
        if path.name.lower().endswith(".gz") and not zipped:
            raise MotionFormatError(path, None, "cannot read: named .gz, but not gzip data")
        raw = bytearray()
        with gzip.open(path, "rb") if zipped else open(path, "rb") as f:
            # A chunk at a time, to the bound (a gzip bomb stops there): f.read(MAX_BYTES + 1)
            # asked for 1 GiB at once, for any file, refused where memory is not overcommitted.
            while len(raw) <= MAX_BYTES and (chunk := f.read(min(_READ_CHUNK, MAX_BYTES + 1 - len(raw)))):
                raw += chunk
        if len(raw) > MAX_BYTES:
            raise MotionFormatError(path, None, f"more than {MAX_BYTES >> 30} GiB of text: not a BVH take")
    except FileNotFoundError:
        raise MotionFormatError(path, None, "file not found") from None
    except (OSError, EOFError, gzip.BadGzipFile, zlib.error) as e:
        raise MotionFormatError(path, None, f"cannot read: {getattr(e, 'strerror', None) or e}") from None
    breaks = raw.count(b"\n") + raw.count(b"\r")
    if breaks > MAX_LINES:  # a small gzip of line breaks: a list of a billion lines (GiBs)
        raise MotionFormatError(path, None, f"more than {MAX_LINES:,} lines: not a BVH take")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    del raw
    # Lines end at CR, LF or CRLF only (str.splitlines also splits at form feeds and the like,
    # which the count above would not bound); no last empty line, as splitlines.
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    if lines and not lines[-1]:
        lines.pop()
    return lines


def _parse_hierarchy(path: Path, lines: list[str]) -> tuple[list[BvhJoint], int]:
    """Returns the joints and the index of the line after ``MOTION``."""
    # Long because it reads the hierarchy line by line, one branch per keyword, each with the
    # checks that name the line at fault: one state machine, read top to bottom.
    joints: list[BvhJoint] = []
    stack: list[int] = []  # joint index per open brace; -2 marks an End Site block
    pending: tuple[str, int] | None = None  # (name, parent) of a JOINT/ROOT awaiting '{'
    i = 0
    while i < len(lines) and not lines[i].strip():
        i += 1
    if i >= len(lines) or lines[i].strip() != "HIERARCHY":
        raise MotionFormatError(path, i + 1, "expected HIERARCHY at the start of the file")
    i += 1
    while i < len(lines):
        tok = lines[i].split()
        lineno = i + 1
        i += 1
        if not tok:
            continue
        kw = tok[0]
        if kw in ("ROOT", "JOINT"):
            if len(tok) < 2:
                raise MotionFormatError(path, lineno, f"{kw} without a name")
            if kw == "ROOT" and joints:
                raise MotionFormatError(path, lineno, "only one ROOT is supported")
            parent = next((s for s in reversed(stack) if s >= 0), -1) if stack else -1
            if kw == "JOINT" and not stack:
                raise MotionFormatError(path, lineno, "JOINT outside any ROOT")
            if len(joints) >= MAX_JOINTS:
                raise MotionFormatError(path, lineno, f"more than the {MAX_JOINTS:,} joints a take may hold")
            if len(stack) >= MAX_DEPTH:  # its ancestors' braces: a hierarchy nested deeper
                raise MotionFormatError(
                    path, lineno, f"joints nested more than the {MAX_DEPTH} levels deep a take may hold"
                )
            pending = (" ".join(tok[1:]), parent)
        elif kw == "End" and len(tok) > 1 and tok[1] == "Site":
            pending = ("__end__", stack[-1] if stack else -1)
        elif kw == "{":
            if pending is None:
                raise MotionFormatError(path, lineno, "'{' without ROOT, JOINT or End Site")
            name, parent = pending
            pending = None
            if name == "__end__":
                stack.append(-2 - parent)  # remember the owner of the end site
            else:
                joints.append(BvhJoint(name, parent, np.zeros(3), []))
                stack.append(len(joints) - 1)
        elif kw == "}":
            if not stack:
                raise MotionFormatError(path, lineno, "unbalanced '}'")
            stack.pop()
        elif kw == "OFFSET":
            if len(tok) != 4:
                raise MotionFormatError(path, lineno, f"OFFSET needs 3 numbers, got {len(tok) - 1}")
            try:
                off = np.array([float(v) for v in tok[1:]])
            except ValueError:
                raise MotionFormatError(path, lineno, f"non-numeric OFFSET {' '.join(tok[1:])!r}") from None
            if not (np.abs(off) <= MAX_VALUE).all():  # NaN fails too
                raise MotionFormatError(path, lineno, f"OFFSET {' '.join(tok[1:])} is beyond ±{MAX_VALUE:g}")
            if not stack:
                raise MotionFormatError(path, lineno, "OFFSET outside a joint")
            top = stack[-1]
            if top >= 0:
                joints[top].offset = off
            else:
                joints[-2 - top].end_site = off
        elif kw == "CHANNELS":
            if not stack or stack[-1] < 0:
                raise MotionFormatError(path, lineno, "CHANNELS outside a joint")
            try:
                n = int(tok[1])
            except (IndexError, ValueError):
                raise MotionFormatError(path, lineno, "CHANNELS needs a count") from None
            names = tok[2:]
            if not 0 <= n <= 6 or len(names) != n:
                raise MotionFormatError(
                    path,
                    lineno,
                    f"CHANNELS {n} lists {len(names)} channels; expected 0 to 6, as many as listed",
                )
            bad = [c for c in names if c not in _VALID_CHANNELS]
            if bad:
                raise MotionFormatError(path, lineno, f"unknown channel {bad[0]!r}")
            dup = next((c for k, c in enumerate(names) if c in names[:k]), None)
            if dup:
                raise MotionFormatError(path, lineno, f"channel {dup} listed twice")
            if joints[stack[-1]].channels:
                raise MotionFormatError(path, lineno, "a second CHANNELS line for the same joint")
            joints[stack[-1]].channels = names
        elif kw == "MOTION":
            if stack:
                raise MotionFormatError(path, lineno, "MOTION before the hierarchy's braces close")
            if not joints:
                raise MotionFormatError(path, lineno, "no joints in HIERARCHY")
            return joints, i
        else:
            raise MotionFormatError(path, lineno, f"unexpected {kw!r} in HIERARCHY")
    raise MotionFormatError(path, len(lines), "file ends before MOTION (truncated?)")


def _motion_header(path: Path, lines: list[str], i: int) -> tuple[int, float]:
    """The ``Frames:`` and ``Frame Time:`` lines at ``i``: the frame count (at most
    MAX_FRAMES, refused before a frame is read) and the frame time."""

    def header(idx: int, key: str) -> str:
        if idx >= len(lines):
            raise MotionFormatError(path, idx, f"file ends before '{key}' (truncated?)")
        line = " ".join(lines[idx].split())  # "Frame\tTime:" as exporters that use tabs write it
        if not line.startswith(key):
            raise MotionFormatError(path, idx + 1, f"expected '{key}', found {line[:40]!r}")
        return line[len(key) :].strip()

    try:
        n_frames = int(header(i, "Frames:"))
    except ValueError:
        raise MotionFormatError(path, i + 1, "Frames: is not an integer") from None
    try:
        frame_time = float(header(i + 1, "Frame Time:"))
    except ValueError:
        raise MotionFormatError(path, i + 2, "Frame Time: is not a number") from None
    if n_frames <= 0:
        raise MotionFormatError(path, i + 1, f"zero frames (Frames: {n_frames})")
    if n_frames > MAX_FRAMES:
        raise MotionFormatError(
            path, i + 1, f"Frames: {n_frames:,} is more than the {MAX_FRAMES:,} a take may hold"
        )
    if not 1e-5 <= frame_time <= 10.0:  # 100 kHz to one frame every 10 s: anything else is no take's
        raise MotionFormatError(path, i + 2, f"Frame Time must be from 1e-05 to 10 seconds, got {frame_time}")
    return n_frames, frame_time


def _parse_motion(path: Path, lines: list[str], i: int, n_channels: int) -> tuple[np.ndarray, float, int]:
    n_frames, frame_time = _motion_header(path, lines, i)
    start = i + 2
    body = lines[start : start + n_frames]
    data = _read_values(body, n_frames * n_channels)
    if data is None:
        # Slow path only on error: find the first offending line.
        for k, ln in enumerate(body):
            vals = ln.split(None, n_channels)  # at most n_channels + 1 strings, however long the line
            if len(vals) != n_channels:
                n = len(vals) if len(vals) < n_channels else n_channels + _count_values(vals[-1])
                raise MotionFormatError(
                    path, start + k + 1, f"frame {k} has {n} values, expected {n_channels}"
                )
            try:
                arr = np.array(vals, dtype=np.float64)
            except ValueError:
                bad = next(v for v in vals if not _is_float(v))
                raise MotionFormatError(
                    path, start + k + 1, f"non-numeric value {bad!r} in frame {k}"
                ) from None
            if not np.isfinite(arr).all():
                raise MotionFormatError(path, start + k + 1, f"non-finite value in frame {k}")
            if not (np.abs(arr) <= MAX_VALUE).all():
                raise MotionFormatError(path, start + k + 1, f"a value beyond ±{MAX_VALUE:g} in frame {k}")
        raise MotionFormatError(
            path, start + len(body), f"file has {len(body)} of {n_frames} frames (truncated?)"
        )
    fps = 1.0 / frame_time
    # Frame times are printed rounded (0.0333333); snap to the intended integer rate.
    if abs(fps - round(fps)) < 1e-3 * fps:
        fps = float(round(fps))
    return data.reshape(n_frames, n_channels), fps, start


#: The most text the motion is split into values at a time. A value's Python string costs
#: up to 17 bytes per byte of text (splitting the whole MOTION section at once took 8.3 GB
#: for 505 MB), so the values are parsed a block at a time into one float array: a few MB
#: over it, however long the take.
_BLOCK_CHARS = 1 << 18
_SPACE = re.compile(r"\s")  # the characters str.split() splits at


def _read_values(body: list[str], total: int) -> np.ndarray | None:
    """The values of ``body``, read as ``np.array(" ".join(body).split(), np.float64)`` would
    read them but a block at a time; None unless they are ``total`` numbers within
    ±MAX_VALUE (the caller then names the line at fault)."""
    # Each value takes a character and a space: a count the text cannot hold is refused
    # before an array of that size is made (a header may declare a million frames).
    if total > (sum(map(len, body)) + len(body) + 1) // 2:
        return None
    out = np.empty(total)
    n = 0
    for words in _value_blocks(body):
        if n + len(words) > total:
            return None
        try:
            vals = np.array(words, dtype=np.float64)
        except ValueError:
            return None
        if not (np.abs(vals) <= MAX_VALUE).all():  # NaN fails too
            return None
        out[n : n + len(vals)] = vals
        n += len(vals)
        del words, vals  # not held while the next block is split
    return out if n == total else None


def _value_blocks(body: list[str]):
    """The words of ``body`` (``" ".join(body).split()``), in lists of about _BLOCK_CHARS of
    text; a longer line is cut at whitespace, so no word is split."""
    block: list[str] = []
    size = 0
    for line in body:
        for piece in _cut(line) if len(line) > _BLOCK_CHARS else (line,):
            block.append(piece)
            size += len(piece) + 1
            if size >= _BLOCK_CHARS:
                yield " ".join(block).split()
                block, size = [], 0
    if block:
        yield " ".join(block).split()


def _cut(line: str):
    """``line`` in pieces of _BLOCK_CHARS or more (the last may be shorter), each ending
    before whitespace or at the line's end."""
    a = 0
    while a < len(line):
        m = _SPACE.search(line, a + _BLOCK_CHARS)
        b = m.start() if m else len(line)
        yield line[a:b]
        a = b


def _count_values(text: str) -> int:
    """``len(text.split())``, counted a block at a time (a line may hold a GiB of values)."""
    return sum(len(piece.split()) for piece in _cut(text))


def _is_float(v: str) -> bool:
    try:
        float(v)
        return True
    except ValueError:
        return False


#: Joint-frames whose float64 transforms are made at a time (56 bytes each: 3.7 MB). A take's
#: were all made at once beside its values, then cast to float32: 20,640 frames of the
#: 101-joint CMU rig took 142 MiB over its values, 39 MiB so (the float32 result's 32). Each
#: frame is computed on its own, so a block's values are the whole take's, bit for bit.
_BLOCK_JOINT_FRAMES = 1 << 16


def _joint_transforms(joints: list[BvhJoint], data: np.ndarray, rule: str) -> tuple[np.ndarray, np.ndarray]:
    """Each joint's local translation (T, J, 3) and rotation (T, J, 4) from its channels
    (the frames of ``data``, (T, channels), however many)."""
    T, J = data.shape[0], len(joints)
    trans = np.empty((T, J, 3))
    rots = np.empty((T, J, 4))
    col = 0
    for j, jt in enumerate(joints):
        ch = jt.channels
        block = data[:, col : col + len(ch)]
        col += len(ch)
        trans[:, j] = jt.offset
        for a, axis in enumerate("XYZ"):
            if axis + "position" in ch:
                p = block[:, ch.index(axis + "position")]
                trans[:, j, a] = p + jt.offset[a] if (j == 0 and rule == "add") else p
        rot_ch = [c for c in ch if c.endswith("rotation")]
        if rot_ch:  # one to three axes, composed in channel order
            order = "".join(c[0] for c in rot_ch)
            rots[:, j] = euler_to_quat(block[:, [ch.index(c) for c in rot_ch]], order)
        else:
            rots[:, j] = (0, 0, 0, 1)
    return trans, rots


def _container_root(joints: list[BvhJoint], parents: list[int]) -> bool:
    """Whether the root is a container, not a joint of the character: a root with a single
    child that either carries position channels of its own (Bandai's joint_Root above Hips)
    or whose name says it is one (iClone's RL_BoneRoot, Maya's *_Root). A real root with
    one child (Hips -> Spine) is kept."""
    container = len(joints) > 1 and sum(1 for p in parents if p == 0) == 1 and parents[1] == 0
    return container and (
        any(c.endswith("position") for c in joints[1].channels) or "root" in joints[0].name.lower()
    )


def _rest_offsets(path: Path, joints: list[BvhJoint], first: np.ndarray) -> np.ndarray:
    """Each joint's bone (J, 3) float32, the root's its first-frame height; ``first``: the
    first frame's local translations (J, 3)."""
    offsets = np.array([jt.offset for jt in joints], np.float64)
    # Position channels below the root replace the OFFSET: their first frame is the bone
    # (exporters that write 6 channels everywhere may leave OFFSET at zero). A joint's
    # translation that changes over the clip is not kept: bones are rigid here. Values
    # within 1e-4 of the OFFSET keep the OFFSET (Bandai writes the same numbers twice).
    for j, jt in enumerate(joints):
        if j and any(c.endswith("position") for c in jt.channels):
            if np.abs(first[j] - offsets[j]).max() > 1e-4:
                offsets[j] = first[j]
    # The root's rest position: its first-frame height above the origin (its OFFSET may be
    # meaningless, as in Bandai); every other joint keeps its bone from above.
    offsets[0] = (0.0, first[0, 1], 0.0)
    return offsets.astype(np.float32)  # every value within MAX_VALUE: the cast cannot overflow


def read_bvh(
    path: str | Path,
    root_position: str | None = None,
    fold_root: bool = True,
) -> Motion:
    """Read a BVH file into a :class:`Motion`.

    ``root_position`` is "replace" or "add" (see the module doc); ``None`` picks the one the
    file's content asks for (:func:`_root_rule`). With ``fold_root``, a root that has a single child (Bandai's
    ``joint_Root``, iClone's ``RL_BoneRoot``) is composed into that child, which becomes
    the root, as PROTOCOL.md prescribes.
    """
    path = Path(path)
    if root_position not in (None, *ROOT_POSITION_RULES):
        raise ValueError(f"root_position must be one of {ROOT_POSITION_RULES}, not {root_position!r}")
    lines = _open_text(path)
    joints, i = _parse_hierarchy(path, lines)
    n_channels = sum(len(j.channels) for j in joints)
    data, fps, _ = _parse_motion(path, lines, i, n_channels)
    del lines  # the text: as large as the values, and not needed again
    rule = root_position or _root_rule(joints, data)
    names = [jt.name for jt in joints]
    parents = [jt.parent for jt in joints]
    fold = fold_root and _container_root(joints, parents)
    rots, root, first = _motion_arrays(joints, data, rule, fold)
    del data
    if fold:
        joints = joints[1:]
        names = names[1:]
        parents = [max(p - 1, -1) for p in parents[1:]]
        parents[0] = -1

    offsets = _rest_offsets(path, joints, first)
    end_sites = {k: jt.end_site.astype(np.float32) for k, jt in enumerate(joints) if jt.end_site is not None}
    skel = Skeleton(tuple(names), np.array(parents), offsets, "Y", 0.01, end_sites)
    name = re.sub(r"(\.bvh)?(\.gz)?$", "", path.name, flags=re.IGNORECASE) or path.name
    return Motion(skel, rots, root, fps, name)


def _motion_arrays(joints: list[BvhJoint], data: np.ndarray, rule: str, fold: bool):
    """The take's local rotations (T, J, 4) and root positions (T, 3), float32, and its first
    frame's local translations (J, 3) float64; with ``fold``, the root composed into its
    only child (index 1 in file order), which takes its place. Made a block of frames at a
    time (_BLOCK_JOINT_FRAMES), each cast as soon as it is made."""
    T, J = len(data), len(joints) - int(fold)
    rots, root = np.empty((T, J, 4), np.float32), np.empty((T, 3), np.float32)
    first = None
    step = max(1, _BLOCK_JOINT_FRAMES // len(joints))
    for a in range(0, T, step):
        trans, r = _joint_transforms(joints, data[a : a + step], rule)
        if fold:
            trans[:, 1] = trans[:, 0] + quat_apply(r[:, 0], trans[:, 1])
            r[:, 1] = quat_mul(r[:, 0], r[:, 1])
            trans, r = trans[:, 1:], r[:, 1:]
        if first is None:
            first = trans[0].copy()
        rots[a : a + step], root[a : a + step] = r, trans[:, 0]
    return rots, root, first


def write_bvh(motion: Motion, path: str | Path, order: str = "ZXY") -> None:
    """Write a motion: 6 channels on the root, 3 on every other joint, rotations in ``order``.

    The root's channels are written as a replacement of its OFFSET (read back with
    ``root_position="replace"``). Written atomically.
    """
    path = Path(path)
    skel = motion.skeleton
    order = order.upper()
    rot_names = " ".join(f"{a}rotation" for a in order)
    out: list[str] = ["HIERARCHY"]

    def emit(j: int, depth: int) -> None:
        pad = "  " * depth
        kw = "ROOT" if skel.parents[j] < 0 else "JOINT"
        out.append(f"{pad}{kw} {skel.names[j]}")
        out.append(f"{pad}{{")
        o = skel.offsets[j]
        out.append(f"{pad}  OFFSET {o[0]:.9g} {o[1]:.9g} {o[2]:.9g}")
        if skel.parents[j] < 0:
            out.append(f"{pad}  CHANNELS 6 Xposition Yposition Zposition {rot_names}")
        else:
            out.append(f"{pad}  CHANNELS 3 {rot_names}")
        kids = skel.children(j)
        for c in kids:
            emit(c, depth + 1)
        if not kids:
            e = skel.end_sites.get(j, np.zeros(3))
            out.extend(
                [
                    f"{pad}  End Site",
                    f"{pad}  {{",
                    f"{pad}    OFFSET {e[0]:.9g} {e[1]:.9g} {e[2]:.9g}",
                    f"{pad}  }}",
                ]
            )
        out.append(f"{pad}}}")

    emit(0, 0)
    # Channel columns follow the depth-first order in which joints were emitted.
    emitted = [skel.index(line.split()[-1]) for line in out if line.lstrip().startswith(("ROOT ", "JOINT "))]
    eul = quat_to_euler(motion.rotations.astype(np.float64), order)
    cols = [motion.root_positions.astype(np.float64)] + [eul[:, j] for j in emitted]
    frames = np.concatenate(cols, axis=1)
    out += ["MOTION", f"Frames: {len(motion)}", f"Frame Time: {1.0 / motion.fps:.9g}"]
    out += [" ".join(f"{v:.9g}" for v in row) for row in frames]
    text = "\n".join(out) + "\n"
    tmp = path.with_name(f".{path.name}.tmp")
    if path.suffix == ".gz":
        with gzip.open(tmp, "wt", encoding="utf-8") as f:
            f.write(text)
    else:
        tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
