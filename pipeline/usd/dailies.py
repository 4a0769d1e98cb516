"""The dailies step: approve a take of a fill, publish the approved take as plain animation.

``approve`` never edits a layer: it copies the shot's latest fill layer
``<stem>.tween.vNNN`` into the next free version with the decision added (on every root
prim that carries ``TweenAPI``: ``tween:reviewStatus = "approved"``, ``tween:approvedTake``,
``tween:approvedBy``, ``tween:approvedAt``, ``tween:approvalNote``; the ``tweenTake``
selection set to the approved take; ``customLayerData["tween"]["approval"]``) and writes a
new review root layer over it. ``publish`` flattens the approved take out of the variants
into ``<stem>.publish.vNNN.<fmt>``: ``over`` specs that author the shot's own SkelAnimation
(rotations, translations, scales at every filled time code, bit for bit the take's
samples), for use as a stronger sublayer over the shot in any USD tool.

Versions are allocated and written the way :mod:`pipeline.usd.write` writes a fill (folder
lock, temp file, hard link that never overwrites).
"""

from __future__ import annotations

import datetime
import getpass
import os
import re
from collections.abc import Iterable
from pathlib import Path

import pipeline.usd  # noqa: F401  (the TweenAPI plugin before any stage)
from pipeline.atomic import writable
from pipeline.errors import ShotError, TweenError
from pipeline.inputs import not_a_file
from pipeline.options import one_line
from pipeline.usd import files, write
from pipeline.usd.diagnostics import error_text, usd_diagnostics
from usd_schemas import tokens

SUFFIX = "_tween"
ANIM_ATTRS = ("rotations", "translations", "scales")
#: Provenance attributes of the fill's animation copied onto the published one.
_PROVENANCE = (tokens.KEY_TIMES, tokens.MODEL, tokens.MODEL_HASH, tokens.MODEL_LICENCE, tokens.JOB_ID,
               tokens.CREATED_AT)  # fmt: skip
_DECISION = {
    "status": (tokens.REVIEW_STATUS, "Token"),
    "take": (tokens.APPROVED_TAKE, "Int"),
    "by": (tokens.APPROVED_BY, "String"),
    "at": (tokens.APPROVED_AT, "String"),
    "note": (tokens.APPROVAL_NOTE, "String"),
}


# --- reading fill layers ------------------------------------------------------------------------


def _open(path: Path, what: str = "fill layer"):
    """The layer at ``path``, opened anonymously (never saved back), or a one-line error."""
    from pxr import Sdf, Tf

    if not os.access(path, os.R_OK):
        raise TweenError(f"{path}: cannot read the {what}: permission denied")
    with usd_diagnostics(fold=False):
        try:
            layer = Sdf.Layer.OpenAsAnonymous(str(path))
        except Tf.ErrorException as e:
            raise TweenError(f"{path}: cannot read the {what}: {error_text(e, str(path))}") from None
    if layer is None:
        raise TweenError(f"{path}: cannot read the {what}")
    return layer


def _roots(layer) -> list:
    """The root prim specs that carry the review state (``tween:reviewStatus``)."""
    return [p for p in layer.rootPrims if tokens.REVIEW_STATUS in p.attributes]


def _animations(layer) -> list:
    """The filled animations of a fill layer: ``def SkelAnimation "<anim>_tween"`` specs."""
    from pxr import Sdf

    found, todo = [], list(layer.rootPrims)
    while todo:
        spec = todo.pop()
        if (
            spec.typeName == "SkelAnimation"
            and spec.specifier == Sdf.SpecifierDef
            and spec.name.endswith(SUFFIX)
        ):
            found.append(spec)
        todo.extend(spec.nameChildren)
    return sorted(found, key=lambda s: s.path)


def _takes(layer) -> list[int]:
    """The take numbers a fill layer holds: its ``tweenTake`` variants (common to every root),
    else the single take's ``tween:take``."""
    sets = [r.variantSets[write.VARIANT_SET] for r in _roots(layer) if write.VARIANT_SET in r.variantSets]
    if sets:
        names = set.intersection(*({v.name for v in s.variants} for s in sets))
        return sorted(int(n[4:]) for n in names if re.fullmatch(r"take\d+", n))
    takes = {
        int(a.attributes[tokens.TAKE].default) for a in _animations(layer) if tokens.TAKE in a.attributes
    }
    return sorted(takes) or [0]


def _read_decision(layer) -> dict | None:
    """The decision authored on the layer's review roots; None while pending."""
    for r in _roots(layer):
        attrs = r.attributes
        status = attrs[tokens.REVIEW_STATUS].default
        if not status or status == "pending":
            continue
        out = {"status": str(status)}
        for key, (name, _) in _DECISION.items():
            if key != "status":
                a = attrs.get(name)
                out[key] = (
                    a.default if a is not None and a.default is not None else (-1 if key == "take" else "")
                )
        return out
    return None


def _fill_layers(out: Path, stem: str) -> dict[int, Path]:
    return write.versions(out, stem)


def _latest(shot: str, out: Path, stem: str) -> tuple[int, Path]:
    versions = _fill_layers(out, stem) if out.is_dir() else {}
    if not versions:
        raise ShotError(shot, f"no fill yet: no {stem}.tween.vNNN layer in {out} (run tween fill first)")
    write.check_series(shot, out, stem)  # another shot's fills: approve and publish took them
    write.check_latest_there(shot, out, stem)  # a fill deleted by hand: not the one before it
    n = max(versions)
    return n, versions[n]


def _fill_folder(shot: str, out_dir: str | os.PathLike | None) -> Path:
    return Path(out_dir) if out_dir else write.default_out_dir(shot)


def _check_shot(shot: str) -> None:
    if why := not_a_file(shot, "shot file"):
        raise ShotError(shot, why)
    write.check_shot_name(shot)


def _who() -> str:
    try:
        return getpass.getuser()
    except Exception:  # no login name, no passwd entry (containers)
        return os.environ.get("USER") or "unknown"


def _describe(d: dict) -> str:
    at = f" at {d['at']}" if d.get("at") else ""
    return f"take {d['take']} by {d.get('by') or 'unknown'}{at}"


# --- decision ----------------------------------------------------------------------------------


_FILL_NAME = re.compile(r"^(?P<stem>.+)\.tween\.v(?P<n>\d+)\.usd[ac]?$")
_KEYS = ("status", "take", "by", "at", "note")


def _metadata(path: Path):
    """The layer's metadata only (``customLayerData``, ``subLayers``): fast even for a
    100 MB fill layer; None when unreadable."""
    from pxr import Sdf, Tf

    from pipeline.usd.diagnostics import usd_diagnostics

    try:
        with usd_diagnostics(fold=False):
            return Sdf.Layer.OpenAsAnonymous(str(path), True)
    except Tf.ErrorException:
        return None


def tween_info(path: Path) -> dict | None:
    """The layer's ``customLayerData["tween"]`` (metadata only); None when unreadable or not
    a regular file (a pipe named like a layer would hold the caller)."""
    layer = _metadata(path) if Path(path).is_file() else None
    return None if layer is None else dict(layer.customLayerData.get("tween", {}))


def _approval(info: dict) -> dict | None:
    appr = dict(info.get("approval", {}))
    return {k: appr.get(k) for k in _KEYS} if appr.get("status") else None


def fill_decision(path, names: Iterable[str] | None = None, read=tween_info) -> dict | None:
    """The decision for the fill layer ``path``: its own approval, else the newest later
    version of its stem approving it (``"of"`` names it); None while pending or unreadable.

    ``names``: the names in its folder, default one listing of it (the dailies list passes
    the listing it shares among the folder's shots). ``read(path)``: the layer's tween
    data, None when unreadable or not a regular file, as :func:`tween_info` (the dailies
    list passes a cached one).
    """
    path = Path(path)
    info = read(path)
    if info is None:
        return None
    if d := _approval(info):
        return {**d, "layer": str(path)}
    m = _FILL_NAME.match(path.name)
    if not m:
        return None
    if names is None:
        try:
            names = os.listdir(path.parent)
        except OSError:
            return None
    # One pattern for every stem: a pattern per stem missed re's cache on a list of 1,000 shots.
    later = {
        int(k["n"]): name
        for name in names
        if (k := _FILL_NAME.match(name)) and k["stem"] == m["stem"] and int(k["n"]) > int(m["n"])
    }
    for _, name in sorted(later.items(), reverse=True):
        cand = read(path.parent / name)
        d = _approval(cand or {})
        if d and dict(cand["approval"]).get("of") == path.name:
            return {**d, "layer": str(path.parent / name)}
    return None


def decision(layer_path, _depth: int = 0) -> dict | None:
    """The dailies decision for a layer, or None (pending, not a tween layer, unreadable).

    ``layer_path`` may be a fill layer (:func:`fill_decision`: a pending one reports the
    approval layer written from it, if any), a review root layer (its strongest fill layer
    decides) or a published layer. Returns ``{"status", "take", "by", "at", "note",
    "layer"}``, ``layer`` being the file that records the decision. Reads layer metadata
    only (cheap).
    """
    path = Path(layer_path)
    if _FILL_NAME.match(path.name):
        return fill_decision(path)
    layer = _metadata(path) if path.is_file() else None
    if layer is None:
        return None
    if d := _approval(dict(layer.customLayerData.get("tween", {}))):
        return {**d, "layer": str(path)}
    if _depth < 4:  # a root layer: its strongest fill layer decides
        for sub in layer.subLayerPaths:
            p = Path(sub) if os.path.isabs(sub) else path.parent / sub
            if _FILL_NAME.match(p.name):
                return decision(p, _depth + 1)
    return None


# --- approve -----------------------------------------------------------------------------------


def _check_approvable(layer, path: Path, take: int) -> None:
    if not _roots(layer) or not _animations(layer):
        raise TweenError(f"{path}: not a usd-tween fill layer (no TweenAPI review state or filled animation)")
    d = _read_decision(layer)
    if d and d["status"] == "approved":
        raise TweenError(
            f"{path}: already approved ({_describe(d)}); a decision is never rewritten: "
            "a new fill is needed to approve another take"
        )
    takes = _takes(layer)
    if take not in takes:
        raise TweenError(
            f"{path}: take {take} is not one of the layer's takes ({', '.join(map(str, takes))})"
        )


def _author_decision(layer, take: int, d: dict) -> None:
    from pxr import Sdf

    for r in _roots(layer):
        for key, (name, tn) in _DECISION.items():
            write.author_attr(r, name, getattr(Sdf.ValueTypeNames, tn), d[key])
        if write.VARIANT_SET in r.variantSets:
            r.variantSelections[write.VARIANT_SET] = f"take{take}"


def _check_approval_options(take, note: str | None, by: str | None) -> None:
    if isinstance(take, bool) or not isinstance(take, int) or take < 0:
        raise TweenError(f"--take {take!r}: expected a take number, 0 or more")
    if note is not None and "\0" in note:
        raise TweenError("--note: contains a NUL character")
    if by is not None and not one_line(by):
        raise TweenError(f"--by {by[:40]!r}: expected the reviewer's name (printable, 1 to 200 characters)")


def _save_approved(src, final: Path, tmp: Path, n: int, review: Path, of: Path, take: int, d: dict) -> None:
    """Writes to ``tmp`` version ``n`` of the fill layer: ``src`` (the layer ``of``) with the
    decision ``d`` on ``take``, naming its ``review`` layer."""
    from pxr import Sdf

    layer = Sdf.Layer.CreateNew(str(tmp))
    if layer is None:
        raise TweenError(f"{final}: cannot write the layer")
    layer.TransferContent(src)
    info = dict(layer.customLayerData.get("tween", {}))
    info.update(version=n, review=review.name, approval={**d, "of": of.name})
    data = dict(layer.customLayerData)
    data["tween"] = info
    layer.customLayerData = data
    with Sdf.ChangeBlock():
        _author_decision(layer, take, d)
    if not layer.Save():
        raise TweenError(f"{final}: cannot write the layer")
    del layer


def approve(
    shot: str, take: int, note: str | None = None, out_dir: str | None = None, by: str | None = None
) -> dict:
    """Records the approval of ``take`` in a new version of the shot's latest fill layer and
    a new review root layer over it; returns {"layer", "review", "version", "of", "take",
    "by", "at", "note"}. ``by`` is the reviewer (default: this process's user). The latest
    layer is read, never written."""
    shot = str(shot)
    _check_approval_options(take, note, by)
    _check_shot(shot)
    stem = write.shot_stem(shot)
    out = _fill_folder(shot, out_dir)
    # Checked before the lock (nothing is created for bad input), then again under it.
    _, first = _latest(shot, out, stem)
    src = _open(first)
    _check_approvable(src, first, take)
    out = write.check_out_dir(shot, str(out))
    shot_layer = _metadata(Path(shot))  # its layer metadata goes into the review layer
    if shot_layer is None:
        raise ShotError(shot, "cannot open as USD")
    created: list[Path] = []
    with files.folder_lock(shot, out, stem, created):
        files.clean_dead_temps(out)
        n_src, path = _latest(shot, out, stem)
        if path != first:  # another writer came first (layers are never rewritten: same name, same file)
            src = _open(path)
            _check_approvable(src, path, take)
        d = {"status": "approved", "take": int(take), "by": by.strip() if by else _who(),
             "at": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"), "note": note or ""}  # fmt: skip
        n = max(write.taken_versions(out, stem)) + 1
        fmt = path.suffix.lstrip(".")
        final = out / f"{stem}.tween.v{n:03d}.{fmt}"
        review = files.review_path(out, stem, n)
        tmp = files.temp_path(final)
        with files.saving(final, tmp):
            _save_approved(src, final, tmp, n, review, path, take, d)
        if not write.link_version(shot, shot_layer, tmp, final, review):
            raise ShotError(shot, f"{final} already exists; never overwritten")
    return {
        "layer": str(final),
        "review": str(review),
        "version": n,
        "of": str(path),
        "of_version": n_src,
        **d,
    }


# --- publish -----------------------------------------------------------------------------------


def _approved_latest(shot: str, out: Path, stem: str) -> tuple[int, Path, object, dict]:
    n, path = _latest(shot, out, stem)
    layer = _open(path)
    if not _roots(layer) or not _animations(layer):
        raise TweenError(f"{path}: not a usd-tween fill layer (no TweenAPI review state or filled animation)")
    d = _read_decision(layer)
    if not d or d["status"] != "approved":
        status = d["status"] if d else "pending"
        raise TweenError(
            f"{path}: nothing approved (the latest fill is {status}); run tween approve {shot} --take N first"
        )
    if d["take"] not in _takes(layer):
        raise TweenError(f"{path}: the approved take {d['take']} is not one of the layer's takes")
    return n, path, layer, d


def _publish_path(shot: str, out: Path, stem: str, n: int, fmt: str | None, dest) -> tuple[Path, str]:
    if dest is None:
        fmt = fmt or "usda"
        return out / f"{stem}.publish.v{n:03d}.{fmt}", fmt
    if not str(dest).strip():  # Path("") is the working folder, named "." in the line
        raise TweenError(f"--out {str(dest)!r}: empty; give the published layer's path")
    dest = Path(dest)
    if dest.suffix not in (".usda", ".usdc", ".usd"):
        raise TweenError(f"{dest}: the published layer must end in .usda, .usdc or .usd")
    if dest.suffix != ".usd":
        if fmt is not None and fmt != dest.suffix[1:]:
            raise TweenError(f"{dest}: --format {fmt} does not match the file's extension")
        fmt = dest.suffix[1:]
    if not dest.parent.is_dir():
        what = "is not a folder" if dest.parent.exists() else "does not exist"
        raise TweenError(f"{dest}: the folder {dest.parent} {what}")
    return dest, fmt or "usda"


def _published_animations(stage, shot: str, src, take: int) -> list[tuple]:
    """(spec, path of its ``take``'s samples in ``src``, the shot's SkelAnimation it fills)
    for each filled animation of the fill layer ``src``."""
    many = any(write.VARIANT_SET in r.variantSets for r in _roots(src))
    anims = []
    for spec in _animations(src):
        orig = spec.path.GetParentPath().AppendChild(spec.name[: -len(SUFFIX)])
        prim = stage.GetPrimAtPath(orig)
        if not prim or prim.GetTypeName() != "SkelAnimation":
            raise ShotError(shot, f"the fill's animation {spec.path} has no SkelAnimation {orig} in the shot")
        if many:
            root = spec.path.GetPrefixes()[0]  # the root prim that holds the tweenTake variants
            vpath = root.AppendVariantSelection(write.VARIANT_SET, f"take{take}").AppendPath(
                spec.path.MakeRelativePath(root)
            )
        else:
            vpath = spec.path
        anims.append((spec, vpath, orig))
    return anims


def _provenance(shot: str, src, path: Path, n: int, take: int, d: dict) -> dict:
    """The published layer's ``tween`` custom data: what filled it, which take of which fill
    layer, its approval, and who published it when."""
    info = dict(src.customLayerData.get("tween", {}))
    now = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    return {
        "kind": "publish",
        "model": info.get("model", ""),
        "modelHash": info.get("modelHash", ""),
        "models": dict(info.get("models", {})),
        **({"licence": dict(info["licence"])} if "licence" in info else {}),
        "jobId": info.get("jobId", ""),
        "take": take,
        "approval": {k: d[k] for k in ("status", "take", "by", "at", "note")},
        "fillLayer": path.name,
        "fillVersion": n,
        "shot": shot,
        "publishedAt": now,
        "publishedBy": _who(),
    }


def _author_published(layer, src, path: Path, final: Path, anims: list[tuple], take: int) -> None:
    """Overs on the shot's SkelAnimations in ``layer``: the take's samples copied as stored
    (bit for bit, without the variant around them), with the fill's provenance attributes."""
    from pxr import Sdf

    for spec, vpath, orig in anims:
        dst = Sdf.CreatePrimInLayer(layer, orig)  # an over, and overs above it
        write.apply_api(dst, tokens.API)
        joints = spec.attributes.get("joints")
        if joints is not None and joints.default is not None:
            write.author_attr(dst, "joints", Sdf.ValueTypeNames.TokenArray, joints.default, uniform=True)
        for name in _PROVENANCE:
            a = spec.attributes.get(name)
            if a is not None and a.default is not None:
                write.author_attr(dst, name, a.typeName, a.default)
        write.author_attr(dst, tokens.TAKE, Sdf.ValueTypeNames.Int, take)
        seed = src.GetAttributeAtPath(vpath.AppendProperty(tokens.SEED))
        if seed is not None and seed.default is not None:
            write.author_attr(dst, tokens.SEED, Sdf.ValueTypeNames.Int, seed.default)
        for name in ANIM_ATTRS:
            a = src.GetAttributeAtPath(vpath.AppendProperty(name)) or spec.attributes.get(name)
            if a is None:
                raise TweenError(f"{path}: {vpath} has no {name} for take {take}")
            # The samples as stored (bit for bit), without the variant around them.
            if not Sdf.CopySpec(src, a.path, layer, dst.path.AppendProperty(name)):
                raise TweenError(f"{final}: cannot copy {a.path}")


class AlreadyPublished(TweenError):
    """The approved take's published layer is there already (it is never overwritten)."""

    def __init__(self, path: Path):
        self.path = path
        super().__init__(f"{path}: already exists; a published layer is never overwritten")


def publish(shot: str, fmt: str | None = None, dest=None, out_dir: str | None = None) -> dict:
    """Writes the approved take of the shot's latest fill layer as a plain animation layer
    (see the module doc); returns {"layer", "of", "take", "format", "animations"}. Never
    overwrites a file."""
    from pxr import Sdf, UsdUtils

    from pipeline.usd.read import open_stage

    shot = str(shot)
    if fmt is not None and fmt not in ("usda", "usdc"):
        raise TweenError(f"--format {fmt!r}: must be usda or usdc")
    _check_shot(shot)
    stem = write.shot_stem(shot)
    out = _fill_folder(shot, out_dir)
    n, path, src, d = _approved_latest(shot, out, stem)
    final, fmt = _publish_path(shot, out, stem, n, fmt, dest)
    if final.exists():
        raise AlreadyPublished(final)
    if not writable(final.parent):
        where = "another --out" if dest is not None else "--out PATH"
        raise TweenError(f"{final}: the folder {final.parent} is read-only (use {where})")
    stage = open_stage(shot)
    take = int(d["take"])
    anims = _published_animations(stage, shot, src, take)
    provenance = _provenance(shot, src, path, n, take, d)
    tmp = files.temp_path(final)
    with files.saving(final, tmp):
        layer = Sdf.Layer.CreateNew(str(tmp), {"format": fmt} if final.suffix == ".usd" else {})
        if layer is None:
            raise TweenError(f"{final}: cannot write the layer")
        UsdUtils.CopyLayerMetadata(stage.GetRootLayer(), layer, True, True)
        layer.customLayerData = {"tween": provenance}
        layer.comment = (
            f"Published by usd-tween: take {take} of {path.name}, approved by {d['by']} at {d['at']}. "
            "Plain animation: sublayer it over the shot (stronger)."
        )
        with Sdf.ChangeBlock():
            _author_published(layer, src, path, final, anims, take)
        if not layer.Save():
            raise TweenError(f"{final}: cannot write the layer")
        del layer
    with files.saving(final, tmp):
        if not files.link_new(tmp, final):
            raise AlreadyPublished(final)
    return {"layer": str(final), "of": str(path), "take": take, "format": fmt,
            "animations": [str(o) for _, _, o in anims]}  # fmt: skip
