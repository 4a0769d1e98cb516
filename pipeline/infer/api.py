"""The one interface every in-betweener implements, and the one registry that loads them by kind.

An in-betweener works on its model's skeleton and frame rate (:class:`Inbetweener`) and
declares what it can do in a class attribute ``capabilities`` (:class:`Capabilities`);
callers read that, never ``hasattr``.

A model folder says which family it belongs to in its JSON file's ``"kind"``: ``model.json``
for models on the human (Bandai) skeleton, ``rig.json`` for per-rig models (the store,
:mod:`pipeline.rig.store`, matches characters against their skeletons). :func:`register`
maps a kind to the loader of its family; :func:`load_model` reads the kind and calls it.
Built-in kinds: ``"interpolation"`` (alias ``"interp"``) and ``"spline"`` need no folder;
``"generator-onnx"`` (the shipped human models; a ``model.json`` without ``"kind"`` is one)
and ``"rig-ganimator-onnx"`` (per-rig GANimator; ``"rig"``, the spelling of rig.json files
written before kinds had names, is the same family). See docs/models.md.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np

from pipeline import jsonfile
from pipeline.errors import TweenError
from pipeline.infer.folder import JSON_LIMIT, ModelFolderError, models_root, read_model_json
from pipeline.inputs import read_small_text
from pipeline.motion.clip import Motion
from pipeline.motion.skeleton import Skeleton

MODEL_FILE = "model.json"
RIG_FILE = "rig.json"
#: The kind of a model.json that names none (every model exported before kinds existed).
DEFAULT_KIND = "generator-onnx"


@dataclass(frozen=True)
class Capabilities:
    """What an in-betweener can do beyond ``fill(motion, keys, seed)``.

    ``partial_keys``: ``fill(..., joint_keys=mask)`` takes keys that set some joints only
    (a (K, J + 1) mask: the joints, then the root). ``dna``: ``fill(..., dna=poses)`` takes a
    motion DNA. ``batch``: ``fill_batch(rotations, roots, keys)`` fills (N, T, J, 4) /
    (N, T, 3) windows sharing their keys in one call (:class:`BatchInbetweener`).
    ``any_rig``: fills whatever skeleton the motion carries, in its own joint space (no
    retargeting onto :attr:`Inbetweener.skeleton`). ``novelty``: ``pose_bank`` is a
    (P, J, 3) sample of its training poses, against which the trusted fill measures how
    familiar a shot's keys are (:mod:`pipeline.infer.novelty`). ``per_gap``: fills each gap
    from its own two keys (no window spans a key, so a cut needs no splitting) and keeps
    ``last_gaps``, a JSON-ready record per gap of its latest fill (a motion library).
    ``familiar_credit``: on keys like its training data (or, without a pose bank, on every
    shot) the trusted fill leans to it on long gaps, as its measured lead over the spline there
    earns; False (model.json ``"familiar_credit": false``, which ``tween export`` writes for a
    fine-tune on a studio's takes, whose lead nothing measured): its probes alone decide.

    Probed beside others by the trusted fill (:mod:`pipeline.infer.trust`) as the primary:
    ``probe_margin``, the score (mean log error ratio at the probes) by which another must beat
    it to fill a shot instead; ``keeps_own``: it keeps shots whose keys are as familiar as its
    training data (nothing is probed beside it there), and another fills a shot only where its
    probes beat the spline as well. A later alternative must beat it by its ``probe_margin``
    too (:func:`pipeline.infer.trust.pick`).
    """

    partial_keys: bool = False
    dna: bool = False
    batch: bool = False
    any_rig: bool = False
    novelty: bool = False
    per_gap: bool = False
    familiar_credit: bool = True
    probe_margin: float = 0.0
    keeps_own: bool = False


@runtime_checkable
class Inbetweener(Protocol):
    """Fills every frame of a motion from the values at its key frames.

    ``fill(motion, keys, seed, joint_keys=None, dna=None)``: ``motion`` is on :attr:`skeleton`
    at :attr:`fps` (on any skeleton with ``capabilities.any_rig``); only the frames listed in
    ``keys`` (sorted int indices, at least two) hold real values, the rest are ignored.
    Returns a motion of the same length whose key frames equal the input exactly. Frames
    before the first key and after the last are held. The same seed on the same host gives
    the same output. ``joint_keys`` (with ``capabilities.partial_keys``) marks what each key
    sets; ``dna`` (with ``capabilities.dna``) is a Motion of poses the fill should contain;
    an in-betweener without the capability refuses them (ValueError).
    """

    name: str
    model_hash: str
    fps: float
    skeleton: Skeleton
    capabilities: ClassVar[Capabilities]

    def fill(self, motion: Motion, keys: np.ndarray, seed: int = 0, joint_keys=None, dna=None) -> Motion: ...


class BatchInbetweener(Inbetweener, Protocol):
    """An in-betweener with ``capabilities.batch``."""

    def fill_batch(
        self, rotations: np.ndarray, roots: np.ndarray, keys: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(N, T, J, 4) local rotations and (N, T, 3) root positions of windows sharing
        ``keys`` → the filled (rotations, roots), same shapes."""
        ...


def fill_windows(inb, rots: np.ndarray, roots: np.ndarray, keys: np.ndarray, batch: int,
                 skeleton=None, fps: float | None = None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(N, T, J, 4) local rotations and (N, T, 3) roots of windows sharing ``keys``, filled by
    ``inb`` (seed 0): ``batch`` windows a ``fill_batch`` call when it declares
    ``capabilities.batch``, else one ``fill`` each on ``skeleton`` (default: its own) at
    ``fps`` (default: its own)."""
    if inb.capabilities.batch:
        out_r, out_p = [], []
        for s in range(0, len(rots), batch):
            r, p = inb.fill_batch(rots[s : s + batch], roots[s : s + batch], keys)
            out_r.append(np.asarray(r))
            out_p.append(np.asarray(p))
        return np.concatenate(out_r), np.concatenate(out_p)
    skel = inb.skeleton if skeleton is None else skeleton
    rate = float(inb.fps if fps is None else fps)
    res = [inb.fill(Motion(skel, r, p, rate), keys) for r, p in zip(rots, roots, strict=True)]
    return np.stack([m.rotations for m in res]), np.stack([m.root_positions for m in res])


def refuse_extras(inb, joint_keys=None, dna=None) -> None:
    """ValueError when ``joint_keys`` or ``dna`` is given to an in-betweener that does not
    declare the capability (for ``fill`` implementations)."""
    if joint_keys is not None and not inb.capabilities.partial_keys:
        raise ValueError(f"{inb.name}: this in-betweener takes no partial keys (joint_keys)")
    if dna is not None and not inb.capabilities.dna:
        raise ValueError(f"{inb.name}: this in-betweener takes no motion DNA")


# -- the registry ---------------------------------------------------------------------------
Loader = Callable[[Path | None], Inbetweener]


@dataclass(frozen=True)
class Family:
    """A registered kind: its loader (called with the model folder, or None for a kind that
    needs no folder) and the file its folders hold (``model.json``, ``rig.json`` or None)."""

    kind: str
    loader: Loader
    file: str | None


_FAMILIES: dict[str, Family] = {}
_NAMES: dict[str, str] = {}  # names that load a folderless kind: "interp" → "interpolation"


def register(kind: str, loader: Loader, file: str | None = MODEL_FILE, names: tuple[str, ...] = ()) -> None:
    """Makes ``kind`` loadable by :func:`load_model`.

    ``loader(folder)`` returns the in-betweener of a model folder whose ``file``
    (``"model.json"``, the default, or ``"rig.json"`` for a per-rig model the store matches
    against characters) says ``"kind": kind``. With ``file=None`` the kind needs no folder:
    ``load_model(kind)`` (or any of ``names``) calls ``loader(None)``. Registering a kind
    again replaces its loader.
    """
    if not isinstance(kind, str) or not kind:
        raise ValueError(f"kind must be a non-empty string, not {kind!r}")
    if file not in (MODEL_FILE, RIG_FILE, None):
        raise ValueError(f"file must be {MODEL_FILE!r}, {RIG_FILE!r} or None, not {file!r}")
    _FAMILIES[kind] = Family(kind, loader, file)
    for n in (kind, *names) if file is None else ():
        _NAMES[n] = kind


def unregister(kind: str) -> None:
    """Forgets ``kind`` (and the names that loaded it)."""
    _FAMILIES.pop(kind, None)
    for n in [n for n, k in _NAMES.items() if k == kind]:
        del _NAMES[n]


def kinds(file: str | None | bool = False) -> tuple[str, ...]:
    """The registered kinds, sorted; with ``file`` those whose folders hold that file
    (None: the folderless ones)."""
    return tuple(sorted(k for k, f in _FAMILIES.items() if file is False or f.file == file))


def rig_kinds() -> tuple[str, ...]:
    """The kinds a ``rig.json`` may carry."""
    return kinds(RIG_FILE)


def builtin_names() -> tuple[str, ...]:
    """Every name that loads a folderless kind ("interp", "interpolation", "spline")."""
    return tuple(sorted(_NAMES))


def model_folder(name: str | Path) -> tuple[Path, str] | None:
    """(folder, file) of the model folder ``name`` refers to (the folder itself, else the
    folder of that name under the models root) and the JSON file it holds, or None. A
    model.json anywhere wins over a rig.json."""

    for file in (MODEL_FILE, RIG_FILE):
        for cand in (Path(name), models_root() / name):
            if (cand / file).exists():
                return cand, file
    return None


def folder_kind(folder: str | Path, file: str = MODEL_FILE) -> str:
    """The ``"kind"`` in ``folder``/``file``; a model.json without one is ``DEFAULT_KIND``.
    An unreadable file is a one-line TweenError naming it."""
    folder = Path(folder)

    path = folder / file
    if file == RIG_FILE:  # the rig model's own loader checks the rest of the file
        try:
            kind = jsonfile.loads(read_small_text(path, JSON_LIMIT, file)).get("kind", "rig")
        except (OSError, UnicodeDecodeError, ValueError, AttributeError) as e:
            raise ModelFolderError(f"{path}: cannot read: {e}") from None
        return kind if isinstance(kind, str) else "rig"
    try:
        meta = jsonfile.loads(read_small_text(path, JSON_LIMIT, file))
    except (OSError, UnicodeDecodeError, ValueError):
        meta = None
    if not isinstance(meta, dict):
        read_model_json(folder)  # says what is wrong with the file, in one line
        raise ModelFolderError(f"{path}: not a model.json")
    kind = meta.get("kind", DEFAULT_KIND)
    if not isinstance(kind, str):
        raise ModelFolderError(f"{path}: 'kind' must be a string, not {type(kind).__name__}")
    return kind


def load_folder(folder: str | Path, file: str | None = None) -> Inbetweener:
    """The in-betweener of a model folder, by the kind its model.json or rig.json declares."""

    folder = Path(folder)
    if file is None:
        file = RIG_FILE if (folder / RIG_FILE).exists() and not (folder / MODEL_FILE).exists() else MODEL_FILE
    kind = folder_kind(folder, file)
    family = _FAMILIES.get(kind)
    if family is None or family.file != file:
        known = ", ".join(kinds(file)) or "none"
        raise ModelFolderError(f"{folder / file}: unknown kind {kind!r} (known {file} kinds: {known})")
    return family.loader(folder)


def load_model(name_or_folder: str | Path = "default") -> Inbetweener:
    """The in-betweener ``name_or_folder`` names: a folderless kind ("interp" /
    "interpolation", "spline"), or a model folder (a path, or a folder under the models
    root) loaded by its declared kind.

    ``"default"`` falls back to interpolation only when no model is shipped; another name
    that is no model is FileNotFoundError.
    """
    name = str(name_or_folder)
    if name in _NAMES:
        return _FAMILIES[_NAMES[name]].loader(None)
    found = model_folder(name)
    if found is None:
        broken = _folder_without_json(name)
        if broken is not None:  # its ONNX files are there, model.json is not: a broken model
            read_model_json(broken)  # ModelFolderError: "<folder>/model.json: missing (...)"
        if name == "default":
            _say_no_default(os.environ.get("TWEEN_MODELS"))
            return load_model("interpolation")
        raise FileNotFoundError(f"{name}: no such model (expected a folder with model.json)")
    return load_folder(*found)


def _say_no_default(env: str | None) -> None:
    """A TWEEN_MODELS with no default model: a typo there silently swapped the shipped network
    for interpolation. Not a folder: refused; a folder (of rig models, say): said on stderr."""
    if not env:
        return
    if not Path(env).is_dir():
        raise TweenError(f"TWEEN_MODELS {env}: not a folder of models; unset it to use the shipped ones")
    print(f"tween: warning: TWEEN_MODELS {env} holds no default model (a folder 'default' with model.json): "
          "human characters are filled by interpolation", file=sys.stderr)  # fmt: skip


#: The name callers used before the registry; the same function.
load_inbetweener = load_model


def _folder_without_json(name: str):
    """The model folder ``name`` refers to when it holds .onnx files but no model.json (and is
    no per-rig model, which has rig.json instead), else None."""

    for cand in (Path(name), models_root() / name):
        try:
            if cand.is_dir() and not (cand / RIG_FILE).exists() and any(cand.glob("*.onnx")):
                return cand
        except OSError:
            continue
    return None


# -- the installed families ---------------------------------------------------------------
#: Entry-point groups (setup.py) naming each family's in-betweener class by kind: called with
#: the model folder (model.json or rig.json kinds) or with nothing (folderless kinds, whose
#: every entry name loads it). The packages declare their own families there, so this module
#: imports none of them (a per-rig model sits above the in-betweeners).
GROUPS = {"tween.models": MODEL_FILE, "tween.rig_models": RIG_FILE, "tween.builtin_models": None}
#: Other names of folderless kinds (``interp = interpolation``).
ALIASES = "tween.model_aliases"


def _installed() -> None:

    aliases: dict[str, list[str]] = {}
    for ep in entry_points(group=ALIASES):
        aliases.setdefault(ep.value, []).append(ep.name)
    for group, file in GROUPS.items():
        for ep in entry_points(group=group):

            def loader(folder, ep=ep):
                cls = ep.load()
                return cls() if folder is None else cls(folder)

            register(
                ep.name, loader, file=file, names=tuple(aliases.get(ep.name, ())) if file is None else ()
            )


_installed()


__all__ = [
    "BatchInbetweener",
    "Capabilities",
    "Family",
    "Inbetweener",
    "builtin_names",
    "folder_kind",
    "kinds",
    "load_folder",
    "load_inbetweener",
    "load_model",
    "model_folder",
    "refuse_extras",
    "register",
    "rig_kinds",
    "unregister",
]
