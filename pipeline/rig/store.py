"""The per-rig model store: which trained rig model (``rig.json``) fits a character's skeleton.

A rig model folder holds ``rig.json`` with ``"kind"`` (one registered for rig.json,
:func:`pipeline.infer.api.rig_kinds`: ``"rig-ganimator-onnx"``, or ``"rig"`` as rig.json files
written before kinds had names say), ``name``, ``hash``, ``fps`` and ``skeleton`` = {``names``,
``parents``, ``offsets``, ``up_axis``, ``meters_per_unit``}: the skeleton it was trained on. The store is every such folder directly under the models root
(``$TWEEN_MODELS`` or the repository's ``models/``).

**Matching** (:func:`match_rig`): a character fits a model when

* the joint names are the model's, and every joint's parent is the same joint (by name; the
  order may differ, as a BVH and a USD export of one rig may list joints differently; when
  names repeat, the order must be the model's);
* every bone (each non-root joint's rest offset from its parent, in metres) is within
  ``BONE_RTOL`` = 5 % of the model's, measured against ``max(model bone, 5 % of the model's
  longest bone)`` so that near-zero bones (end sites, coincident joints) do not demand an
  impossible relative precision. The root's offset is its rest *position*, not a bone, and
  is not compared. Lengths are compared in metres (each side's ``metersPerUnit``), so a
  centimetre shot fits a model trained in metres.

When several models fit, the one with the smallest largest relative bone error wins (then
the name). No torch and no model loading here: only JSON.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline import jsonfile
from pipeline.errors import TweenError
from pipeline.inputs import broken_link, frame_rate_trouble, read_small_text

#: The most bytes rig.json may hold (pipeline.infer.folder.JSON_LIMIT, not imported here: the
#: CLI's start-up reads this module without the in-betweeners).
JSON_LIMIT = 8 << 20

BONE_RTOL = 0.05  # relative bone-length tolerance
BONE_FLOOR = 0.05  # bones are compared against at least this fraction of the longest bone


class RigModelError(TweenError):
    """A rig model folder is unusable (bad rig.json)."""


@dataclass(frozen=True)
class RigModelInfo:
    """What ``rig.json`` says about a model, without loading it."""

    folder: Path
    name: str
    hash: str
    fps: float
    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray  # (J, 3) rest translations, model units
    up_axis: str
    meters_per_unit: float
    meta: dict

    def bone_lengths_m(self) -> np.ndarray:
        return np.linalg.norm(self.offsets, axis=-1) * self.meters_per_unit


def is_rig_folder(path: str | Path) -> bool:
    return (Path(path) / "rig.json").is_file()


def read_rig_json(folder: str | Path) -> RigModelInfo:
    """Parses and checks ``folder/rig.json``; RigModelError (one line, naming the file) if bad."""
    path = Path(folder) / "rig.json"
    try:
        meta = jsonfile.loads(read_small_text(path, JSON_LIMIT, "rig.json"))
    except FileNotFoundError:
        what = broken_link(path) or "no such file"
        raise RigModelError(f"{path}: {what} (a rig model folder holds rig.json)") from None
    except (OSError, UnicodeDecodeError, ValueError) as e:  # ValueError: not JSON, nested too deeply
        raise RigModelError(f"{path}: cannot read: {broken_link(path) or e}") from None
    try:
        from pipeline.infer.api import rig_kinds

        if not isinstance(meta, dict) or meta.get("kind") not in rig_kinds():
            others = ", ".join(k for k in rig_kinds() if k != "rig")
            raise ValueError(f'"kind" is not "rig" nor another rig model kind ({others})')
        sk = meta["skeleton"]
        names = tuple(str(n) for n in sk["names"])
        parents = np.asarray(sk["parents"], np.int64).reshape(-1)
        offsets = np.asarray(sk["offsets"], np.float64).reshape(-1, 3)
        up = str(sk.get("up_axis", "Y")).upper()
        mpu = float(sk.get("meters_per_unit", 0.01))
        if not (len(names) == len(parents) == len(offsets)) or not names:
            raise ValueError("skeleton names, parents and offsets differ in length")
        if parents[0] != -1 or any(not (-1 <= p < j) for j, p in enumerate(parents[1:], 1)):
            raise ValueError("skeleton parents are not in parent-before-child order with one root")
        if up not in ("Y", "Z"):
            raise ValueError(f"up_axis must be Y or Z, not {up!r}")
        if not (mpu > 0 and np.isfinite(mpu)) or not np.isfinite(offsets).all():
            raise ValueError("meters_per_unit or offsets are not finite positive numbers")
        if why := frame_rate_trouble(meta["fps"]):  # 0 was refused only later, by the shot's keys
            raise ValueError(f"'fps' {why}")
        return RigModelInfo(
            folder=Path(folder),
            name=str(meta["name"]),
            hash=str(meta["hash"]),
            fps=float(meta["fps"]),
            names=names,
            parents=parents,
            offsets=offsets,
            up_axis=up,
            meters_per_unit=mpu,
            meta=meta,
        )
    except (KeyError, TypeError, ValueError) as e:
        what = f"missing {e}" if isinstance(e, KeyError) else str(e)
        raise RigModelError(f"{path}: not a rig model: {what}") from None


def models_root() -> Path:
    from pipeline.infer.generator_onnx import models_root as _root

    return _root()


def rig_models(root: str | Path | None = None) -> list[RigModelInfo]:
    """Every rig model directly under ``root`` (default: the models root), sorted by folder.
    A folder with a broken rig.json is skipped with a warning on stderr."""
    root = Path(root) if root is not None else models_root()
    out = []
    if not root.is_dir():
        return out
    for p in sorted(root.iterdir()):
        if not is_rig_folder(p):
            continue
        try:
            out.append(read_rig_json(p))
        except RigModelError as e:
            print(f"tween: warning: skipping rig model: {e}", file=sys.stderr)
    return out


def _permutation(model_names, model_parents, names, parents) -> np.ndarray | None:
    """perm[m] = index in ``names`` of model joint m, or None when the topologies differ."""
    names, parents = tuple(names), np.asarray(parents, np.int64)
    if len(names) != len(model_names):
        return None
    if names == tuple(model_names) and np.array_equal(parents, model_parents):
        return np.arange(len(names))
    if len(set(names)) != len(names) or set(names) != set(model_names):
        return None
    idx = {n: i for i, n in enumerate(names)}
    perm = np.array([idx[n] for n in model_names], np.int64)
    for m, p in enumerate(model_parents):
        mine = parents[perm[m]]
        if (p < 0) != (mine < 0) or (p >= 0 and names[mine] != model_names[p]):
            return None
    return perm


def bone_errors(info: RigModelInfo, perm: np.ndarray, bone_lengths_m) -> np.ndarray:
    """Relative error of each non-root bone against the model's (see the module doc)."""
    model = info.bone_lengths_m()
    mine = np.asarray(bone_lengths_m, np.float64)[perm]
    floor = BONE_FLOOR * model[1:].max() if len(model) > 1 else 0.0
    err = np.abs(mine - model) / np.maximum(np.maximum(model, floor), 1e-12)
    err[0] = 0.0  # the root's offset is a position, not a bone
    return err


def match_rig(info: RigModelInfo, names, parents, bone_lengths_m, rtol: float = BONE_RTOL):
    """(perm, worst relative bone error) when the skeleton fits ``info``, else (None, reason)."""
    perm = _permutation(info.names, info.parents, names, parents)
    if perm is None:
        return None, _topology_difference(info, names, parents)
    err = bone_errors(info, perm, bone_lengths_m)
    worst = int(np.argmax(err))
    if err[worst] > rtol:
        have = float(np.asarray(bone_lengths_m, np.float64)[perm[worst]])
        want = float(info.bone_lengths_m()[worst])
        return None, (
            f"bone {info.names[worst]!r} is {have:.4g} m, the model's {want:.4g} m "
            f"({err[worst] * 100:.0f} % off, tolerance {rtol * 100:.0f} %)"
        )
    return perm, float(err[worst])


def _topology_difference(info: RigModelInfo, names, parents) -> str:
    names = tuple(names)
    if len(names) != len(info.names):
        return f"{len(names)} joints, the model has {len(info.names)}"
    missing = [n for n in info.names if n not in set(names)]
    if missing:
        return f"no joint {missing[0]!r}"
    for m, p in enumerate(info.parents):
        if names.count(info.names[m]) != 1:
            return "joint names repeat and their order differs from the model's"
        i = names.index(info.names[m])
        mine = names[parents[i]] if parents[i] >= 0 else None
        want = info.names[p] if p >= 0 else None
        if mine != want:
            return f"joint {info.names[m]!r} has parent {mine!r}, the model's has {want!r}"
    return "the joint hierarchy differs"


def find_rig(
    names, parents, bone_lengths_m, root: str | Path | None = None, rtol: float = BONE_RTOL
) -> tuple[RigModelInfo, np.ndarray] | None:
    """The best-fitting rig model in the store and its joint permutation, or None."""
    best = None
    for info in rig_models(root):
        perm, err = match_rig(info, names, parents, bone_lengths_m, rtol)
        if perm is not None and (best is None or (err, info.name) < (best[0], best[1].name)):
            best = (err, info, perm)
    return None if best is None else (best[1], best[2])


def find_rig_model(
    names, parents, bone_lengths, root: str | Path | None = None, rtol: float = BONE_RTOL
) -> Path | None:
    """The folder of the rig model whose skeleton is ``names``/``parents`` (exactly, up to
    joint order) with bone lengths (metres, one per joint, the root's ignored) within
    ``rtol``; None when no stored model fits."""
    found = find_rig(names, parents, bone_lengths, root, rtol)
    return None if found is None else found[0].folder


def no_model_hint(shot: str, prim: str, names, root: str | Path | None = None) -> str:
    """The second half of the one-line refusal of a rig that fits no model at all."""
    root = Path(root) if root is not None else models_root()
    try:
        shown = root.resolve().relative_to(Path.cwd().resolve())
    except ValueError:
        shown = root
    stem = Path(shot).name.split(".")[0] or "rig"
    return (
        f"{prim} ({len(names)} joints, root {names[0]}) matches no human mapping and no rig model in "
        f"{shown}/; train one with: tween train-rig {shot} --skeleton {prim} --out {shown}/{stem}"
    )
