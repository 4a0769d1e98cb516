"""One reference clip of a rig, from a UsdSkel shot or a BVH file, as a :class:`Motion`.

The motion is in the skeleton's own space (what the SkelAnimation holds, or the BVH's), the
joint names are the USD joints' leaf names (or the BVH names) in the source's order, and
``offsets`` are the rest translations the source gives (USD ``restTransforms``; BVH
``OFFSET``, root: its first-frame height). The skeleton's ``up_axis`` is the stage's up
axis expressed in skeleton space (through the skeleton's world transform).
"""

from __future__ import annotations

import math
import os
import zipfile
from pathlib import Path

import numpy as np

from pipeline.data.split import shared_data_dir
from pipeline.errors import ShotError, TweenError
from pipeline.inputs import not_a_file
from pipeline.motion.bvh import MAX_BYTES, MAX_FRAMES, is_bvh
from pipeline.motion.clip import Motion
from pipeline.motion.rotations import QUAT_EPS
from pipeline.motion.skeleton import MAX_LENGTH, METERS_PER_UNIT, Skeleton, topology_problem

#: The frame rates a clip may have, and so those a rig model trains at (``--fps``).
FPS_RANGE = (1.0, 1000.0)
#: The most joints a clip .npz may declare: far above the rigs here (Bandai 21, CMU 31, the
#: elephant 27) and a film rig's thousands; it bounds the Python work on names and hierarchy.
MAX_JOINTS = 10_000


class RigSourceError(TweenError):
    """A reference clip cannot be read: one line naming the file."""

    def __init__(self, path, message: str):
        self.path = str(path)
        super().__init__(f"{self.path}: {message}")


def parse_frames(spec: str | None) -> tuple[int, int | None] | None:
    """``"0:1511"`` → (0, 1511) (a half-open frame-index range; ``"100:"`` → (100, None): to
    the clip's end); ``None``/"" → None. Indices count from the clip's first frame: a
    negative one is refused (it read as "to the end", whatever its value)."""
    if not spec:
        return None
    try:
        a, b = spec.split(":")
        lo = int(a) if a.strip() else 0
        hi = int(b) if b.strip() else None
    except ValueError:
        raise TweenError(f"--frames {spec!r}: expected START:STOP, e.g. 0:1511") from None
    if lo < 0 or (hi is not None and hi < 0):
        raise TweenError(f"--frames {spec!r}: frame indices count from 0 (the clip's first frame)")
    return lo, hi


def _slice(path, motion: Motion, frames) -> Motion:
    if frames is None:
        return motion
    lo, hi = frames
    hi = len(motion) if hi is None else hi
    if not (0 <= lo < hi <= len(motion)):
        raise RigSourceError(path, f"frames {lo}:{hi} are not inside the clip's {len(motion)} frames")
    if hi - lo < 2:  # inside, but no motion: it said "not inside the clip"
        raise RigSourceError(path, f"frames {lo}:{hi} hold {hi - lo} frame; a clip needs at least 2")
    return motion.slice(lo, hi)


def _up_in_skeleton(stage_up: str, skel_to_world: np.ndarray) -> str:
    """The stage's up axis as seen from skeleton space (nearest coordinate axis)."""
    up = np.array([0.0, 1.0, 0.0]) if stage_up == "Y" else np.array([0.0, 0.0, 1.0])
    r = skel_to_world[:3, :3]
    r = r / np.linalg.norm(r, axis=0, keepdims=True)
    local = r.T @ up  # world → skeleton for a rotation (scale removed)
    axis = int(np.argmax(np.abs(local)))
    if axis == 0 or local[axis] < 0:
        return ""
    return "YZ"[axis - 1]


def _from_usd(path: Path, skeleton: str | None) -> Motion:
    from pipeline.usd.read import anim_values, read_shot

    shot = read_shot(path)
    chars = shot.characters
    if skeleton:
        match = [c for c in chars if c.skel_path == skeleton]
        match = match or [c for c in chars if c.skel_path.rstrip("/").endswith("/" + skeleton.strip("/"))]
        if len(match) != 1:
            have = ", ".join(c.skel_path for c in chars)
            what = "matches several skeletons" if match else "is not an animated skeleton"
            raise RigSourceError(path, f"skeleton {skeleton!r} {what} (the shot has: {have})")
        char = match[0]
    else:
        char = max(chars, key=lambda c: len(c.joints))
    times, step = _clip_times(path, shot, char)
    rot, tr, _ = anim_values(shot.stage, char, times)
    # Skeleton order; joints the animation does not list keep their rest pose.
    from pipeline.usd.read import to_skeleton_order

    rot, tr = to_skeleton_order(char, rot, tr)
    up = _up_in_skeleton(shot.up_axis, char.skel_to_world)
    if not up:
        raise RigSourceError(path, f"{char.skel_path}: the stage's up axis is X or down in skeleton space")
    why = topology_problem(char.joints, char.parents)
    if why:
        raise ShotError(path, f"skeleton topology: {why}", char.skel_path)
    skel = Skeleton(
        char.names, char.parents, char.rest_trans.astype(np.float32), up, shot.meters_per_unit * _scale(char)
    )
    fps = shot.tcps / float(step.mean())
    fps = float(np.round(fps)) if abs(fps - np.round(fps)) < 1e-3 else fps  # 3023.000157… time codes
    name = f"{path.name.split('.')[0]}:{char.skel_path.rstrip('/').rsplit('/', 2)[-2]}"
    return Motion(skel, rot, tr[:, 0], fps, name)


def _clip_times(path: Path, shot, char) -> tuple[np.ndarray, np.ndarray]:
    """The times the clip is read at (the animation's samples, or every frame between its
    first and last where they are uneven) and the step between them. Uneven samples outside
    the stage range are refused before a frame is read (a stray sample at 1e9 made the reader
    allocate hundreds of GiB); read_shot refuses a range over MAX_FRAMES frames."""
    from pipeline.usd.read import TIME_EPS

    times = char.sample_times
    if len(times) < 2:
        raise RigSourceError(path, f"{char.anim_path} has {len(times)} time samples; a clip needs at least 2")
    step = np.diff(times)
    if np.abs(step - step.mean()).max() <= 1e-3 * step.mean():
        return times, step
    # Uneven samples: read the animation at every frame of its range instead.
    out = times[(times < shot.start - TIME_EPS) | (times > shot.end + TIME_EPS)]
    if len(out):
        raise ShotError(
            path,
            f"time sample {out[0]:g} is outside the stage range {shot.start:g}-{shot.end:g}",
            char.anim_path,
        )
    lo, hi = np.round(times[0]), np.round(times[-1])
    return np.arange(lo, hi + 1.0), np.ones(1)


def _scale(char) -> float:
    """The skeleton's world scale (a scaled SkelRoot makes the units larger)."""
    return float(np.cbrt(abs(np.linalg.det(char.skel_to_world[:3, :3]))))


SHARED = "shared:"  # a source path under the shared data folder, stored relative to it


def portable_path(path: str | Path) -> str:
    """``path`` as rig.json stores it: ``shared:<relative>`` under the shared data folder
    (which each checkout finds beside it), so that a model folder made on one machine
    names its clip on another; else its absolute path (a relative one would name the clip
    only from the folder the training ran in)."""
    p = Path(path).resolve()
    try:
        return SHARED + p.relative_to(shared_data_dir().resolve()).as_posix()
    except (ValueError, OSError):
        return os.path.abspath(path)


def stored_path(path: str) -> Path:
    """The file a rig.json source path names (:func:`portable_path`'s inverse)."""
    return shared_data_dir() / path[len(SHARED) :] if path.startswith(SHARED) else Path(path)


def load_rig_source(
    path: str | Path, skeleton: str | None = None, frames: tuple[int, int] | None = None
) -> Motion:
    """The clip in ``path`` (``.usd/.usda/.usdc/.usdz`` or ``.bvh/.bvh.gz``).

    USD: ``skeleton`` is the Skeleton prim path (or its trailing part); by default the
    animated skeleton with the most joints. ``frames`` = (start, stop) frame indices into
    the clip (stop exclusive, -1 = the end).
    """
    path = Path(path)
    if why := not_a_file(path, "clip file"):
        raise RigSourceError(path, why)
    if path.suffix.lower() in (".usd", ".usda", ".usdc", ".usdz"):
        motion = _from_usd(path, skeleton)
    elif is_bvh(path):
        from pipeline.motion.bvh import read_bvh

        if skeleton:
            raise RigSourceError(path, "--skeleton applies to USD shots; a BVH holds one skeleton")
        motion = read_bvh(path)
    elif path.suffix.lower() == ".npz":
        if skeleton:
            raise RigSourceError(path, "--skeleton applies to USD shots; an .npz holds one skeleton")
        motion = load_npz(path)
    else:
        raise RigSourceError(path, "not a USD shot (.usd/.usda/.usdc/.usdz) or a BVH (.bvh/.bvh.gz)")
    _check_values(path, motion)
    return _slice(path, motion, frames)


def _check_values(path: Path, m: Motion) -> None:
    """RigSourceError unless the clip's shapes agree and its numbers are finite, its rate
    positive (a damaged .npz gave a rig.json full of NaN)."""
    s = m.skeleton
    J = len(s.names)
    if J == 0:
        raise RigSourceError(path, "names: the skeleton has no joints")
    seen = set()
    for n in s.names:
        if n in seen:
            raise RigSourceError(
                path, f"names: joint name {n!r} is given twice (a rig's joint names are unique)"
            )
        seen.add(n)
    rot, root = np.asarray(m.rotations), np.asarray(m.root_positions)
    shapes = {"parents": (np.shape(s.parents), (J,)), "offsets": (np.shape(s.offsets), (J, 3)),
              "rotations": (rot.shape, (len(rot), J, 4)), "root_positions": (root.shape, (len(rot), 3))}  # fmt: skip
    for what, (have, want) in shapes.items():
        if have != want:
            raise RigSourceError(path, f"{what} of shape {have}, expected {want} for {J} joints")
    if len(rot) < 2:
        raise RigSourceError(path, f"{len(rot)} frame(s): a clip to learn from needs at least 2")
    if not (np.isfinite(m.fps) and m.fps > 0):
        raise RigSourceError(path, f"frame rate {m.fps!r}: not a positive number")
    lo, hi = FPS_RANGE
    if not lo <= m.fps <= hi:  # an .npz at 1e-300 or 1e300 fps trained
        raise RigSourceError(
            path, f"frame rate {m.fps:g}: must be from {lo:g} to {hi:g} fps (as train-rig trains)"
        )
    if not (np.isfinite(s.meters_per_unit) and s.meters_per_unit > 0):
        raise RigSourceError(path, f"meters per unit {s.meters_per_unit!r}: not a positive number")
    lo, hi = METERS_PER_UNIT
    if not lo <= s.meters_per_unit <= hi:
        raise RigSourceError(
            path,
            f"meters per unit {s.meters_per_unit:g} is not a unit a character is measured in ({lo:g} to {hi:g} m)",
        )
    for what, a in (("offsets", s.offsets), ("rotations", rot), ("root positions", root)):
        if not np.isfinite(a).all():
            raise RigSourceError(path, f"its {what} hold NaN or infinite values")
    for what, a in (("offsets", s.offsets), ("root positions", root)):
        if a.size and np.abs(a).max() > MAX_LENGTH:
            raise RigSourceError(path, f"its {what} hold a value beyond ±{MAX_LENGTH:g} units")
    _check_quaternions(path, m.skeleton.names, rot)


def _check_quaternions(path: Path, names, rot: np.ndarray) -> None:
    """RigSourceError naming the first frame and joint whose quaternion is not a rotation
    (length 0, worded as the USD reader words it)."""
    n = np.linalg.norm(rot.astype(np.float64), axis=-1)
    bad = n <= QUAT_EPS
    if bad.any():
        t, j = (int(i[0]) for i in np.nonzero(bad))
        q = ", ".join(f"{x:g}" for x in rot[t, j])
        raise RigSourceError(
            path,
            f"rotations: joint {names[j]!r} at frame {t} is not a rotation "
            f"(quaternion ({q}) has length {n[t, j]:.3g})",
        )


def save_npz(motion: Motion, path: str | Path) -> None:
    """The clip as a self-contained ``.npz`` (hosts without usd-core or the data folder)."""
    s = motion.skeleton
    np.savez_compressed(
        path,
        names=np.array(s.names),
        parents=s.parents,
        offsets=s.offsets,
        up_axis=np.array(s.up_axis),
        meters_per_unit=np.array(s.meters_per_unit),
        rotations=motion.rotations,
        root_positions=motion.root_positions,
        fps=np.array(motion.fps),
        name=np.array(motion.name),
    )


NPZ_KEYS = (
    "names",
    "parents",
    "offsets",
    "up_axis",
    "meters_per_unit",
    "rotations",
    "root_positions",
    "fps",
    "name",
)
NUMBERS = ("parents", "offsets", "meters_per_unit", "rotations", "root_positions", "fps")


def load_npz(path: str | Path) -> Motion:
    """The clip ``tween rig-extract`` saved in ``path`` (RigSourceError naming it otherwise)."""
    try:
        with zipfile.ZipFile(path) as z:
            a = _npz_arrays(path, z)
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile) as e:
        # BadZipFile for an empty, truncated or other file, ValueError for a damaged array.
        why = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise RigSourceError(path, f"not a clip .npz written by `tween rig-extract`: {why}") from None
    _check_npz(path, a)
    try:
        with np.errstate(over="ignore"):  # float64 beyond float32 is inf here, refused by _check_values
            names = tuple(str(n) for n in a["names"])
            skel = Skeleton(names, a["parents"], a["offsets"], str(a["up_axis"]), float(a["meters_per_unit"]))
            return Motion(skel, a["rotations"], a["root_positions"], float(a["fps"]), str(a["name"]))
    except (ValueError, IndexError, TypeError) as e:
        why = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise RigSourceError(path, f"not a clip .npz written by `tween rig-extract`: {why}") from None


def _npz_arrays(path, z: zipfile.ZipFile) -> dict:
    """The clip's arrays, read only once every header (shape and type, before its data) fits
    a clip (:func:`_check_npz_sizes`): each array is allocated as its header declares, so a
    small file of compressed zeros declaring millions of frames made train-rig take 16 GB."""
    listed = set(z.namelist())
    members = {k: k if k in listed else f"{k}.npy" for k in NPZ_KEYS}  # as np.load finds them
    heads = {}
    for k, member in members.items():
        if member not in listed:
            raise KeyError(f"{k} is not a file in the archive")
        with z.open(member) as f:
            heads[k] = _npy_header(k, f)
    _check_npz_sizes(path, heads)
    out = {}
    for k, member in members.items():
        with z.open(member) as f:
            out[k] = np.lib.format.read_array(f, allow_pickle=False)
    return out


def _npy_header(key: str, f) -> tuple[tuple, np.dtype]:
    """The shape and type an .npy member declares, read without its data."""
    fmt = np.lib.format
    version = fmt.read_magic(f)
    if version == (1, 0):
        shape, _, dtype = fmt.read_array_header_1_0(f)
    elif version == (2, 0):
        shape, _, dtype = fmt.read_array_header_2_0(f)
    else:  # 3.0 is for structured types' field names, never a clip's
        raise ValueError(f"{key}: .npy format {version[0]}.{version[1]}")
    return shape, dtype


def _check_npz_sizes(path, heads: dict) -> None:
    """RigSourceError unless the arrays ``heads`` declares ((shape, dtype) by key) hold at
    most MAX_FRAMES frames (a shot's limit), MAX_JOINTS joints and MAX_BYTES in all."""
    for k in ("rotations", "root_positions"):
        shape = heads[k][0]
        if shape and shape[0] > MAX_FRAMES:
            raise RigSourceError(path, f"{k}: {shape[0]:,} frames; a clip holds at most {MAX_FRAMES:,}")
    for k, axis in (("names", 0), ("parents", 0), ("offsets", 0), ("rotations", 1)):
        shape = heads[k][0]
        if len(shape) > axis and shape[axis] > MAX_JOINTS:
            raise RigSourceError(
                path, f"{k}: {shape[axis]:,} joints; a clip's rig has at most {MAX_JOINTS:,}"
            )
    size = sum(math.prod(shape) * dtype.itemsize for shape, dtype in heads.values())
    if size > MAX_BYTES:
        raise RigSourceError(
            path, f"its arrays hold {size:,} bytes; a clip holds at most {MAX_BYTES >> 30} GiB"
        )


def _check_npz(path, a: dict) -> None:
    """RigSourceError unless the .npz's numbers are real numbers (a complex array lost its
    imaginary part with a warning), its scalars scalars and its parents one hierarchy (the
    bounds on its values hold for every source: _check_values)."""
    for k in NUMBERS:
        if a[k].dtype.kind not in "iuf" or (k == "parents" and a[k].dtype.kind == "f"):
            want = "integers" if k == "parents" else "real numbers"
            raise RigSourceError(path, f"{k}: {a[k].dtype} values, expected {want}")
    for k in ("up_axis", "meters_per_unit", "fps", "name"):
        if a[k].ndim:
            raise RigSourceError(path, f"{k}: an array of shape {a[k].shape}, expected one value")
    names, parents = a["names"], a["parents"]
    fits = names.ndim == parents.ndim == 1 and len(names) == len(parents)  # else Skeleton says so
    why = fits and len(names) and topology_problem([str(n) for n in names], parents)
    if why:
        raise RigSourceError(path, f"parents: {why}")
