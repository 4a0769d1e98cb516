"""A human model's folder: where models live, ``model.json`` read and checked, the ONNX
files checked whole; one-line errors naming the file. No onnxruntime here."""

from __future__ import annotations

import hashlib
import json
import os
import stat
import zipfile
from pathlib import Path

import numpy as np

from pipeline import jsonfile
from pipeline.errors import TweenError
from pipeline.inputs import broken_link, frame_rate_trouble, read_small_text

#: The most bytes a model folder's JSON file (model.json, rig.json) may hold: a few KB each
#: shipped; a pipe or a device in its place blocked or ate memory (read_small_text).
JSON_LIMIT = 8 << 20


def models_root() -> Path:
    env = os.environ.get("TWEEN_MODELS")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "models"


#: The most intra-op threads TWEEN_ORT_THREADS may ask for (a farm host's cores, and then some).
MAX_ORT_THREADS = 1024


def ort_threads() -> int:
    """``TWEEN_ORT_THREADS`` (default 1), a whole number from 1 to MAX_ORT_THREADS; TweenError
    naming the setting otherwise (a bad one was blamed on the model file onnxruntime loaded,
    and 0 or -1 were taken)."""
    text = os.environ.get("TWEEN_ORT_THREADS", "1")
    value = int(text.strip()) if text.strip().isascii() and text.strip().isdigit() else 0
    if not 1 <= value <= MAX_ORT_THREADS:
        raise TweenError(
            f"TWEEN_ORT_THREADS={text!r}: must be a whole number of threads from 1 to {MAX_ORT_THREADS:,}"
        )
    return value


def find_model(name: str) -> Path | None:
    p = Path(name)
    if (p / "model.json").exists():
        return p
    cand = models_root() / name
    return cand if (cand / "model.json").exists() else None


def experimental(name: str) -> str | None:
    """Why the human model ``name`` is experimental (its model.json's ``experimental``), or
    None for a shipped model, a built-in or a model that is not there."""
    folder = find_model(name)
    if folder is None:
        return None
    try:
        why = jsonfile.loads(read_small_text(folder / "model.json", JSON_LIMIT, "model.json")).get(
            "experimental"
        )
    except (OSError, ValueError, AttributeError):
        return None  # the fill itself says what is wrong with the folder
    return str(why) if why else None


class ModelFolderError(TweenError, ValueError):
    """A model folder that cannot be used: one line naming the file and what is wrong."""


# model.json: the keys every model has, and the types of those the farm reads.
_NUMBER = (int, float)
_REQUIRED = {"name": str, "hash": str, "fps": _NUMBER, "multiple": int, "files": dict}
_OPTIONAL = {
    "root": str,
    "pad": str,
    "pad_tail": int,
    "min_window": int,
    "max_gap": int,
    "receptive_field": int,
    "mirror_average": bool,
    "feet_anchor": bool,
    "feet_orient": bool,
    "generator": dict,
    "kind": str,
    "experimental": str,  # why no production shot should use it (said at every fill that does)
    "library": str,  # a motion library shipped beside the network (shipped_library)
    "beside": list,  # model folders inside it, probed beside the network after the library (beside_models)
    "familiar_credit": bool,  # false: the trusted fill's probes alone decide (Capabilities)
    "format": int,
}
#: The model folder layout this release reads (model.json's "format"; one without is format 1).
FORMAT = 1
#: Settings with one value left: the one every shipped model has (the code for any other went
#: with the experiments that tried it; models/default/HISTORY.md has what they gave). A model
#: may leave them out (``pad``: models before v4's card held no pad layout, and ran with the
#: last frame held: none of them ships); any other value is refused. ``generator``'s are the
#: network's inputs and output (pipeline.networks.generator.GeneratorConfig drops them).
#: The most frames ``pad_tail`` and ``min_window`` may ask for: a fill's window grows by them,
#: and its memory with it (10^8 asked 31 GiB of every fill).
PAD_MAX = 1024
#: The largest ``multiple`` (the frames a window is padded to a multiple of: 32 shipped); a
#: window is padded by up to as many frames (10^9 asked 313 GiB of a fill).
MULTIPLE_MAX = 1024
FIXED = {"pad": "hold-key", "root": "generator", "mirror_average": False}
RETIRED = {"residual": True, "tta": True, "noise_schedule": False, "key_mask": False,
           "full_timing": False, "rotation": "6d"}  # fmt: skip


def without_retired(generator: dict, where) -> dict:
    """A generator config (model.json's "generator", a checkpoint's "model") without the
    :data:`RETIRED` switches; ModelFolderError naming ``where`` where one is set otherwise."""
    for key, want in RETIRED.items():
        if generator.get(key, want) != want:
            raise ModelFolderError(
                f"{where}: generator.{key} is {generator[key]!r}; this release runs {want!r} only"
            )
    return {k: v for k, v in generator.items() if k not in RETIRED}


_TYPE_NAMES = {
    list: "an array",
    str: "a string",
    int: "an integer",
    bool: "true or false",
    dict: "an object",
    _NUMBER: "a number",
}


def _json_type(v) -> str:
    return {dict: "an object", list: "an array", str: "a string", bool: "a boolean", type(None): "null"}.get(
        type(v), "a number"
    )


def read_json_object(path: str | Path, kind: str, missing: str = "missing") -> dict:
    """``path``, a model folder's JSON file (``kind``: model.json, rig.json), as a JSON object;
    or ModelFolderError naming it in one line: ``missing`` where it is not there, a broken
    link, a pipe or device (read_small_text: opened without blocking, at most JSON_LIMIT
    bytes), not JSON, nested too deeply, or not an object. The one reader of these files,
    so that a damaged one reads the same, and neither hangs nor eats memory, wherever read."""
    path = Path(path)
    try:
        text = read_small_text(path, JSON_LIMIT, kind)
    except FileNotFoundError:
        raise ModelFolderError(f"{path}: {broken_link(path) or missing}") from None
    except (OSError, UnicodeDecodeError) as e:
        if odd := broken_link(path):  # a link loop: named, not "too many levels of symbolic links"
            raise ModelFolderError(f"{path}: {odd}, not a {kind}") from None
        raise ModelFolderError(f"{path}: cannot read: {getattr(e, 'strerror', None) or e}") from None
    try:
        meta = jsonfile.loads(text)
    except json.JSONDecodeError as e:
        raise ModelFolderError(
            f"{path}: not valid JSON (line {e.lineno}, column {e.colno}: {e.msg})"
        ) from None
    except ValueError as e:  # nested too deeply, a key given twice
        raise ModelFolderError(f"{path}: {e}") from None
    if not isinstance(meta, dict):
        raise ModelFolderError(f"{path}: expected a JSON object, found {_json_type(meta)}")
    return meta


def read_model_json(folder: str | Path) -> dict:
    """``folder``/model.json, checked: readable JSON, an object with every required key of
    the right type; or ModelFolderError naming the file."""
    path = Path(folder) / "model.json"
    rig = Path(folder) / "rig.json"
    if not os.path.lexists(path) and (odd := broken_link(rig)):
        # A rig model folder whose rig.json is a broken link: that file is what is wrong.
        raise ModelFolderError(f"{rig}: {odd}, not a rig.json")
    meta = read_json_object(
        path, "model.json", "missing (a model folder holds model.json beside its .onnx files)"
    )
    missing = [k for k in _REQUIRED if k not in meta]
    if missing:
        raise ModelFolderError(f"{path}: missing key(s) {', '.join(repr(k) for k in missing)}")
    for key, want in (*_REQUIRED.items(), *_OPTIONAL.items()):
        if key not in meta:
            continue
        v = meta[key]
        # JSON true/false are not numbers here, and 30.0 is not an integer.
        if (isinstance(v, bool) and want is not bool) or not isinstance(v, want):
            raise ModelFolderError(f"{path}: {key!r} must be {_TYPE_NAMES[want]}, not {_json_type(v)}")
    if why := frame_rate_trouble(meta["fps"]):  # 1e308 overflowed into warnings in the fill
        raise ModelFolderError(f"{path}: 'fps' {why}")
    for key in ("multiple", "max_gap", "receptive_field"):
        if key in meta and not meta[key] > 0:
            raise ModelFolderError(f"{path}: {key!r} must be positive, not {meta[key]!r}")
    for key in ("pad_tail", "min_window"):
        if not 0 <= meta.get(key, 0) <= PAD_MAX:
            raise ModelFolderError(f"{path}: {key!r} must be 0 to {PAD_MAX} frames, not {meta[key]!r}")
    if meta["multiple"] > MULTIPLE_MAX:
        raise ModelFolderError(
            f"{path}: 'multiple' must be 1 to {MULTIPLE_MAX} frames, not {meta['multiple']!r}"
        )
    files = meta["files"]
    if not isinstance(files.get("generator"), str) or not files["generator"]:
        raise ModelFolderError(f"{path}: 'files' must name the generator's ONNX file ('generator': \"...\")")
    for role, name in files.items():
        if not isinstance(name, str) or not name:
            raise ModelFolderError(f"{path}: files.{role} must be a file name, not {_json_type(name)}")
    if meta.get("format", FORMAT) != FORMAT:
        raise ModelFolderError(
            f"{path}: 'format' is {meta['format']}; this release reads format {FORMAT} model folders"
        )
    for key, want in FIXED.items():
        if meta.get(key, want) != want:
            raise ModelFolderError(f"{path}: {key!r} is {meta[key]!r}; this release runs {want!r} only")
    without_retired(meta.get("generator", {}), path)
    return meta


def check_onnx_file(path: Path) -> None:
    """ModelFolderError unless ``path`` is there, non-empty, and reads as a whole ONNX model:
    its top-level protobuf fields (an ONNX ModelProto) all fit in the file and include the
    graph. Cheap (it seeks over the graph), so a truncated or empty file is named at load
    time instead of failing inside onnxruntime on the first fill."""
    try:
        st = path.stat()
        size = st.st_size
        if not stat.S_ISREG(st.st_mode):  # a pipe blocks the open for ever, a device reads without end
            raise ModelFolderError(
                f"{path}: not a regular file (a folder, pipe, socket or device), not an ONNX model"
            )
        f = path.open("rb")
    except FileNotFoundError:
        raise ModelFolderError(f"{path}: missing (named in model.json's 'files')") from None
    except OSError as e:
        raise ModelFolderError(f"{path}: cannot read: {e.strerror or e}") from None
    if size == 0:
        f.close()
        raise ModelFolderError(f"{path}: empty file (not an ONNX model)")
    bad = f"{path}: truncated or not an ONNX model ({size} bytes)"

    def varint() -> int:
        out = shift = 0
        while True:
            b = f.read(1)
            if not b or shift > 63:
                raise ModelFolderError(bad)
            out |= (b[0] & 0x7F) << shift
            shift += 7
            if b[0] < 0x80:
                return out

    graph = False
    with f:
        while f.tell() < size:
            tag = varint()
            field, wire = tag >> 3, tag & 7
            if field == 0:
                raise ModelFolderError(bad)
            if wire == 0:
                varint()
            elif wire in (1, 2, 5):
                n = {1: 8, 5: 4}.get(wire) or varint()
                if f.tell() + n > size:
                    raise ModelFolderError(bad)
                f.seek(n, os.SEEK_CUR)
                graph |= field == 7 and wire == 2  # ModelProto.graph
            else:
                raise ModelFolderError(bad)
    if not graph:
        raise ModelFolderError(f"{path}: not an ONNX model (no graph in its {size} bytes)")


# Inference settings in model.json that change what a fill gives. ``root`` changes it too
# but was never hashed; it stays out so that earlier models keep their hashes.
HASHED_SETTINGS = ("pad", "mirror_average", "pad_tail", "min_window", "feet_anchor", "feet_orient",
                   "familiar_credit")  # fmt: skip


def files_hash(folder: str | Path, names, settings: dict | None = None) -> str:
    """A model's hash: its files' bytes (in the order of ``names``) plus the inference
    settings given. Layers and take digests record it, so it is computed from the files
    when a model loads (:func:`check_hash`), not taken on the word of its JSON."""
    h = hashlib.sha256()
    for name in names:
        h.update(hashlib.sha256((Path(folder) / name).read_bytes()).hexdigest().encode())
    if settings:  # models exported before these settings keep their hash
        h.update(json.dumps(settings, sort_keys=True).encode())
    return h.hexdigest()[:16]


def model_hash(folder: str | Path, meta: dict) -> str:
    """The hash of a human model folder: its ``files`` (by name) and HASHED_SETTINGS."""
    settings = {k: meta[k] for k in HASHED_SETTINGS if k in meta}
    return files_hash(folder, sorted(meta["files"].values()), settings)


def check_hash(path: Path, stated: str, computed: str) -> None:
    """ModelFolderError where ``path`` (model.json, rig.json) states another hash than its
    files give: a file or a hashed setting changed after the export, so every layer filled
    with it would name a model it is not."""
    if stated != computed:
        raise ModelFolderError(
            f"{path}: 'hash' is {stated!r} but its files and settings hash to {computed!r} "
            "(changed after export: export the model again)"
        )


def shipped_library(folder: str | Path, meta: dict) -> Path | None:
    """The motion library a model folder ships beside its network (``model.json``'s
    ``"library"``, relative to the folder), which the trusted fill probes beside the network
    (pipeline.fill.api); None without one. ModelFolderError where the name leaves the folder
    or names no library."""
    name = meta.get("library")
    if not name:
        return None
    path = Path(folder) / "model.json"
    lib = Path(folder) / name
    if Path(name).is_absolute() or ".." in Path(name).parts:
        raise ModelFolderError(f"{path}: 'library' must be a folder inside the model folder, not {name!r}")
    if not (lib / "library.json").is_file():
        raise ModelFolderError(f"{path}: 'library' names {name!r}, which holds no library.json")
    return lib


def beside_models(folder: str | Path, meta: dict) -> tuple[Path, ...]:
    """The models a model folder ships beside its network (``model.json``'s ``"beside"``:
    folders inside the model folder, each a model folder of its own), which the trusted fill
    probes after its library (pipeline.fill.api); () without any. Inside, so that a copy of the
    folder carries them. ModelFolderError where an entry is not a folder inside it holding a
    model.json."""
    names = meta.get("beside") or []
    path = Path(folder) / "model.json"
    out = []
    for name in names:
        if not isinstance(name, str) or not name or Path(name).is_absolute() or ".." in Path(name).parts:
            raise ModelFolderError(
                f"{path}: 'beside' must list folders inside the model folder, not {name!r}"
            )
        other = Path(folder) / name
        if not (other / "model.json").is_file():
            raise ModelFolderError(f"{path}: 'beside' names {name!r}, which holds no model.json")
        out.append(other)
    return tuple(out)


#: The most poses a model's pose bank may hold (4,096 shipped): the bank is read whole, as
#: float32, at every load (a 1.2 MB file of compressed zeros declaring 10^7 poses took 3.8 GB).
POSE_BANK_MAX = 1_000_000


def check_pose_bank(path: Path, joints: int) -> None:
    """ModelFolderError unless the ``poses`` array of the pose bank ``path`` declares (in its
    .npy header, read before any data) a real float (P, ``joints``, 3) of 1 to
    POSE_BANK_MAX poses: numpy allocates an array as its header declares."""
    fmt = np.lib.format
    try:
        with zipfile.ZipFile(path) as z, z.open("poses.npy") as f:
            version = fmt.read_magic(f)
            if version not in ((1, 0), (2, 0)):
                raise ValueError(f".npy format {version[0]}.{version[1]}")
            read = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
            shape, _, dtype = read(f)
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile) as e:
        why = " ".join(str(e).split()) or type(e).__name__
        raise ModelFolderError(f"{path}: not a pose bank ({why})") from None
    if len(shape) == 3 and shape[1] != joints:
        raise ModelFolderError(f"{path}: a pose bank of {shape[1]} joints for a model of {joints}")
    if dtype.kind != "f" or len(shape) != 3 or shape[2] != 3 or not 1 <= shape[0] <= POSE_BANK_MAX:
        raise ModelFolderError(
            f"{path}: not a pose bank of 1 to {POSE_BANK_MAX:,} poses of {joints} joints "
            f"(poses of shape {shape}, type {dtype})"
        )
