"""A motion library shipped as a human model (``model.json`` kind ``"motion-library"``):
``tween fill --model NAME`` fills from the library alone, trusted against the spline, with no
network. Its terms are the capture's own, so a library of commercially usable takes is a human
model a studio may use commercially (models/cmu-library).

``model.json``: ``kind`` ``"motion-library"``, ``name``, ``hash`` (``library-`` and the
library's hash: a library changed after its card is refused), ``library`` (a folder inside the
model folder, as :func:`pipeline.infer.folder.shipped_library` checks it), ``licence``,
``commercial`` and ``sources`` (models/README.md)."""

from __future__ import annotations

from pathlib import Path

from pipeline.infer.folder import ModelFolderError, read_json_object, shipped_library
from pipeline.library.infer import LibraryInbetweener

KIND = "motion-library"


class LibraryModel(LibraryInbetweener):
    """The library a ``motion-library`` model folder names, under the folder's name."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        path = self.folder / "model.json"
        meta = read_json_object(path, "model.json")  # a pipe, a device, deep JSON: one line
        if meta.get("kind") != KIND:
            raise ModelFolderError(f"{path}: not a {KIND} model")
        if not isinstance(meta.get("name"), str) or not meta["name"].strip():
            raise ModelFolderError(f"{path}: 'name' must be a non-empty string")
        if not isinstance(meta.get("library"), str):
            raise ModelFolderError(f"{path}: 'library' must name the library's folder")
        super().__init__(str(shipped_library(self.folder, meta)))
        if meta.get("hash") not in (None, self.model_hash):  # the library was changed after the card
            raise ModelFolderError(f"{path}: 'hash' is {meta['hash']!r}; its library is {self.model_hash!r}")
        self.meta = meta
        self.name = meta["name"]
