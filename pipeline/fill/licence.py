"""The licence of what filled a character: a model folder's ``licence`` (model.json or
rig.json, inherited from the capture it was trained on; models/README.md), a library's
(``library.json``, as the studio stated it). Recorded in the fill's JSON and its layer so that
a studio knows, shot by shot, under which terms the in-betweens it ships were made."""

from __future__ import annotations

from pathlib import Path

from pipeline.infer.folder import ModelFolderError, find_model, read_json_object

#: What a folder that states no licence is recorded as (a model exported before licences).
NOT_STATED = "not stated"
#: The built-in in-betweeners learned nothing: no data's terms reach their fills.
NO_WEIGHTS = "none (no trained weights)"


def folder_licence(folder: str | Path, file: str = "model.json") -> str:
    """``folder/file``'s ``licence`` (NOT_STATED when it has none); ModelFolderError naming
    the file when it is not a string, or the file cannot be read (read_json_object: a file
    replaced by a pipe after its model was loaded blocked a fill for ever)."""
    path = Path(folder) / file
    value = read_json_object(path, file).get("licence", NOT_STATED)
    if not isinstance(value, str) or not value.strip():
        raise ModelFolderError(f"{path}: 'licence' must be a non-empty string, not {value!r}")
    return value


def model_licence(name: str) -> str:
    """The licence of the human model ``name`` (a folder, or a name under the models root);
    NO_WEIGHTS for a built-in that is no folder (interpolation, the spline)."""
    folder = find_model(name)
    return NO_WEIGHTS if folder is None else folder_licence(folder)


def library_licence(manifest: dict) -> str:
    """A library's licence as ``tween library build --licence`` recorded it."""
    value = manifest.get("licence")
    return str(value) if value else NOT_STATED


def describe(licences: dict[str, str]) -> str:
    """One line for a layer attribute: ``name: licence`` for each in-betweener, ``; `` between."""
    return "; ".join(f"{name}: {lic}" for name, lic in licences.items())
