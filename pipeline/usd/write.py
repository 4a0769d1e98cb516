"""Writing the fill layer (versioned, atomic, Sdf-level) and the review root layer.

The filled animation is a sibling SkelAnimation (``<anim>_tween``) with TweenAPI applied;
the Skeleton's ``skel:animationSource`` is pointed at it from the fill layer, which is the
strongest sublayer of a new review root layer, so the animator's files are never written
and the original animation stays beside the fill for comparison. Several takes go into
one ``tweenTake`` variant set on the shot's root prim (the attributes live only inside
the variants, so no local opinion of the animator's layers can hide them).
"""

from __future__ import annotations

import datetime
import glob
import json
import os
import re
import stat
import unicodedata
from pathlib import Path

import numpy as np

import pipeline.usd  # noqa: F401
from pipeline.atomic import locked, writable
from pipeline.errors import ShotError, TweenError
from pipeline.inputs import broken_link, not_a_file
from pipeline.outputs import remove_created
from pipeline.usd import files
from pipeline.usd.diagnostics import error_text, usd_diagnostics
from usd_schemas import tokens

VARIANT_SET = tokens.TAKE_VARIANT_SET
NAME_MAX = 255  # bytes in a file name (Linux, macOS, Windows' NTFS in UTF-16 units)


def shot_stem(shot: str) -> str:
    return Path(shot).name.split(".")[0]


_MADE = re.compile(r"^[^.]+\.(?P<kind>tween|review|publish)\.v\d+\.usd[acz]?$", re.IGNORECASE)
_MADE_KINDS = {"tween": "a fill layer", "review": "a review layer", "publish": "a published layer"}


def made_layer(path: str | Path) -> str | None:
    """What ``path`` is by its name when it is one of the layers a fill, an approval or a
    publish writes (``<stem>.tween.vNNN.usda``: "a fill layer"), else None (a shot)."""
    m = _MADE.match(Path(path).name)
    return _MADE_KINDS[m.group("kind").lower()] if m else None


def check_shot_name(shot: str, new: bool = False) -> None:
    """ShotError when ``shot`` is named so that no fill can be made of it: a layer usd-tween
    made (its versions would be looked for under its own name, and its review would chain
    over it), a name starting with a dot or too long for its layers' names, a path holding a
    control character. ``new``: ``shot`` is about to be written (``tween convert``); the
    same names are refused, a layer's name said as such."""
    made = made_layer(shot)
    if made and new:
        kind = _MADE.match(Path(shot).name)["kind"].lower()
        raise ShotError(shot, f"is named like {made} (<stem>.{kind}.vNNN.usd*), which `tween fill` "
                        "refuses as a shot; give the shot another name")  # fmt: skip
    if made:
        raise ShotError(
            shot, f"is {made}, not a shot: give the shot it was made from ({shot_stem(shot)}.usd*)"
        )
    # USD refuses an asset path holding one (C0, DEL, C1: category Cc), and fills open the shot by it.
    bad = next((c for c in str(shot) if unicodedata.category(c) == "Cc"), None)
    if bad is not None:
        raise ShotError(
            shot,
            f"its path holds the control character {bad!r}, which USD refuses in a layer's path; rename it",
        )
    if not shot_stem(shot):  # ".sh.usda": hidden layers, one series for every such shot there
        raise ShotError(
            shot, "its name starts with a dot: its layers are named after the part before the first dot"
        )
    # The longest name written for it is a take's temp, ".<stem>.take000.<hash>.npz.<pid@host>.<rand>.tmp"
    # (44 bytes and the owner over the stem; 16 spare): a 250-byte name failed there, named instead.
    room = NAME_MAX - len(files.owner_tag().encode()) - 60
    stem = shot_stem(shot).encode("utf-8", "surrogateescape")
    if len(stem) > room:
        raise ShotError(
            shot, f"the part of its name before the first dot is {len(stem)} bytes, and its layers' names "
            f"add to it (a file name holds {NAME_MAX}): at most {room} here; give it a shorter name",
        )  # fmt: skip


def versions(out_dir: Path, stem: str) -> dict[int, Path]:
    """The shot's fill layers in ``out_dir`` by version number."""
    pat = re.compile(rf"^{re.escape(stem)}\.tween\.v(\d+)\.usd[ac]?$")
    out = {}
    for p in out_dir.glob(f"{glob.escape(stem)}.tween.v*.usd*"):  # a name may hold [ or *
        m = pat.match(p.name)
        if m:
            out[int(m.group(1))] = p
    return out


def taken_versions(out_dir: Path, stem: str) -> set[int]:
    """The version numbers in use in ``out_dir``: fill layers, and review layers (a dead
    writer's review of no fill keeps its number until it is cleaned up). A new version, of
    a fill or an approval, takes the next one."""
    review = re.compile(rf"^{re.escape(stem)}\.review\.v(\d+)\.usd[ac]?$")
    used = set(versions(out_dir, stem))
    used |= {
        int(m[1]) for p in out_dir.glob(f"{glob.escape(stem)}.review.v*.usd*") if (m := review.match(p.name))
    }
    return used


def latest_review(shot: str, out_dir: str | Path | None = None) -> Path | None:
    """The review layer of the shot's latest fill (``<stem>.review.vNNN``, beside its fill
    layer in ``out_dir`` or the default folder), or None when the shot has no fill there.
    ShotError when that review layer is missing or one of its layers is (a review of the
    older fill, or of the shot alone, would pass for this one)."""
    out = Path(out_dir) if out_dir else default_out_dir(shot)
    found_versions = versions(out, shot_stem(shot)) if out.is_dir() else {}
    check_latest_there(shot, out, shot_stem(shot), review_hint=True)
    if not found_versions:
        return None
    check_series(shot, out, shot_stem(shot))  # not another shot's fill as this one's
    return review_of(found_versions[max(found_versions)])


def _stacked_fill(review: Path, name: str) -> str:
    """The file name of the fill layer ``name`` (``<stem>.tween.vNNN``) as ``review`` stacks
    it (a fill may be .usdc); ``name.usda`` when the layer does not say, or is not a regular
    file (a pipe held USD's read for ever: approve, publish and the dailies list hung)."""
    from pxr import Sdf, Tf

    try:
        layer = None if not_a_file(review, "review layer") else Sdf.Layer.OpenAsAnonymous(str(review), True)
    except Tf.ErrorException:
        layer = None
    subs = [Path(s).name for s in layer.subLayerPaths] if layer is not None else []
    return next((s for s in subs if s.rsplit(".", 1)[0] == name), f"{name}.usda")


#: A fill or review layer of any shot, by name (one pattern for every stem: the dailies list
#: reads a folder of many shots with it).
_VERSION_LAYER = re.compile(r"^(?P<stem>[^.]+)\.(?P<kind>tween|review)\.v(?P<n>\d+)\.usd[ac]?$")


def missing_latest(stem: str, names) -> int | None:
    """The version of the shot ``stem``'s newest layer among ``names`` (one listing of its
    folder) where that is a review layer whose fill layer is not there (deleted by hand) and
    no writer's temp of it is (:func:`check_latest_there`'s case); None otherwise. A writer
    still writing, or killed, has its temp there (its review layer is written first)."""
    fills, reviews, temps = set(), set(), set()
    for name in names:
        if (m := _VERSION_LAYER.match(name)) and m["stem"] == stem:
            (fills if m["kind"] == "tween" else reviews).add(int(m["n"]))
        elif (m := files.FILL_TEMP.match(name)) and m["stem"] == stem:
            temps.add(int(m["n"]))
    newest = max(reviews, default=0)
    if newest <= max(fills, default=0) or newest in temps:
        return None
    return newest


def missing_fill(out: Path, stem: str, n: int) -> Path:
    """The fill layer of version ``n`` that :func:`missing_latest` found gone, as its review
    layer stacks it (a fill may be .usdc)."""
    return out / _stacked_fill(files.review_path(out, stem, n), f"{stem}.tween.v{n:03d}")


def check_latest_there(shot: str, out: Path, stem: str, review_hint: bool = False) -> None:
    """ShotError when the shot's newest version in ``out`` is a review layer whose fill layer
    is gone (deleted by hand) and no writer's temp of it is there (:func:`missing_latest`):
    the highest fill left is an older one, which review, approve and publish would take for
    "the latest fill" (an approval of it would be recorded as the replaced fill's).
    ``review_hint``: say how to review the fill before it (``tween review`` takes a review
    layer)."""
    try:
        newest = missing_latest(stem, os.listdir(out))
    except OSError:  # no folder (no fill yet), or one that cannot be listed
        return
    if newest is None:
        return
    check_series(shot, out, stem)  # another shot's fills are refused as that
    review = files.review_path(out, stem, newest)
    missing = missing_fill(out, stem, newest)
    fills_there = versions(out, stem)
    earlier = (
        f", or review an earlier fill by its layer: tween review {files.review_path(out, stem, max(fills_there))}"
        if fills_there and review_hint
        else ""
    )
    raise ShotError(
        str(missing),
        f"the latest fill of {shot} is not there (its review layer {review.name} is); "
        f"run tween fill again{earlier}",
    )


def review_of(fill: str | Path) -> Path:
    """The review layer written with the fill layer ``fill`` (same folder, stem and version),
    checked by :func:`check_review`; ShotError naming it when it is not there."""
    fill = Path(fill)
    name = fill.name.replace(".tween.", ".review.", 1)
    found = sorted(fill.parent.glob(f"{name.rsplit('.', 1)[0]}.usd*"))
    if not found:
        raise ShotError(
            str(fill), f"its review layer {fill.parent / name.rsplit('.', 1)[0]}.usda is not there"
        )
    check_review(found[0])
    return found[0]


def check_review(review: str | Path) -> None:
    """ShotError unless every layer a review layer stacks (its fill, the shot) is there: USD
    composes without a missing sublayer, so the review would show the shot unfilled, or a
    fill with no character under it."""
    from pxr import Sdf, Tf

    why = not_a_file(review, "review layer") if os.path.exists(review) else _link_loop(review, "review layer")
    if why is not None:  # a pipe would block USD's read for ever
        raise ShotError(str(review), why)
    try:
        with usd_diagnostics(fold=False):
            layer = Sdf.Layer.OpenAsAnonymous(str(review))
    except Tf.ErrorException as e:
        raise ShotError(str(review), f"cannot read the review layer: {error_text(e, str(review))}") from None
    if layer is None:
        return  # not a layer USD reads: opening the stage names it
    for sub in layer.subLayerPaths:
        path = sub if os.path.isabs(sub) else os.path.join(os.path.dirname(str(review)), sub)
        if not os.path.exists(path):
            raise ShotError(
                str(review), f"the layer it stacks, {sub}, is not there ({os.path.normpath(path)})"
            )


def _link_loop(path: str | Path, kind: str) -> str | None:
    """The phrase for ``path`` when it is a link loop, else None: inputs.not_a_file says "a
    link to nothing" of one, and dailies' read of one failed as "permission denied"."""
    why = broken_link(path)
    return f"{why}, not a {kind}" if why and "loop" in why else None


def _recorded(path: Path) -> dict:
    """The ``tween`` record of a layer written here ({} for one USD cannot read); ShotError
    naming it when it is not a regular file (a pipe would block USD's read for ever)."""
    from pxr import Sdf, Tf

    why = not_a_file(path, "fill layer") if os.path.exists(path) else _link_loop(path, "fill layer")
    if why is not None:  # a link to nothing passes: nothing USD reads, so no record
        raise ShotError(str(path), f"{why}; remove it or use --out-dir")
    try:
        layer = Sdf.Layer.OpenAsAnonymous(str(path))
    except Tf.ErrorException:
        return {}
    return dict(layer.customLayerData.get("tween", {})) if layer else {}


def _shot_name(path: str) -> str:
    """A shot's file name without its USD extension: a fill records the shot it was made from."""
    return re.sub(r"\.usd[acz]?$", "", Path(path).name, flags=re.IGNORECASE)


def _same_shot(info: dict, shot: str) -> bool:
    return not info.get("shot") or _shot_name(info["shot"]) == _shot_name(shot)


def find_job(out_dir: Path, stem: str, job_id: str, shot: str) -> dict | None:
    """The result of a layer in ``out_dir`` already written by ``job_id`` for ``shot``, if any."""
    if not job_id:
        return None
    for n, p in sorted(versions(out_dir, stem).items()):
        info = _recorded(p)
        if info.get("jobId") == job_id and _same_shot(info, shot):
            return {
                "layer": str(p),
                "review": str(out_dir / info.get("review", "")),
                "version": n,
                "takes": int(info.get("takes", 1)),
                "model": info.get("model", ""),
                "model_hash": info.get("modelHash", ""),
                "models": dict(info.get("models", {})),
                "licence": dict(info.get("licence", {})),
            }
    return None


def check_series(shot: str, out_dir: Path, stem: str) -> None:
    """ShotError when the ``<stem>.tween.vNNN`` layers in ``out_dir`` are another shot's: two
    shots whose names share the part before the first dot (``shot.a.usda``, ``shot.b.usda``)
    would share one version series, and each one's latest fill would be the other's."""
    found = versions(out_dir, stem) if out_dir.is_dir() else {}
    if not found:
        return
    info = _recorded(found[max(found)])
    if not _same_shot(info, shot):
        raise ShotError(
            shot, f"its layers would be {stem}.tween.vNNN in {out_dir}, which hold the fills of "
            f"{Path(info['shot']).name}; name it so that the part before its first dot is its own, or use --out-dir",
        )  # fmt: skip


def apply_api(spec, name: str) -> None:
    from pxr import Sdf

    spec.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=[name]))


def author_attr(spec, name, type_name, value=None, uniform=False):
    from pxr import Sdf

    a = spec.attributes.get(name) or Sdf.AttributeSpec(
        spec, name, type_name, Sdf.VariabilityUniform if uniform else Sdf.VariabilityVarying
    )
    if value is not None:
        a.default = value
    return a


def _author_samples(layer, spec, data: dict, extra=None) -> None:
    """Each take's samples of the animation joints; ``extra`` (:func:`_extra_joints`): the
    take's values with those of the joints the animation lists that the fill does not, merged in."""
    from pxr import Sdf, Vt

    ra = author_attr(spec, "rotations", Sdf.ValueTypeNames.QuatfArray).path
    ta = author_attr(spec, "translations", Sdf.ValueTypeNames.Float3Array).path
    sa = author_attr(spec, "scales", Sdf.ValueTypeNames.Half3Array).path
    rot = np.ascontiguousarray(data["rot"], np.float32)
    tr = np.ascontiguousarray(data["trans"], np.float32)
    sc = np.ascontiguousarray(data["scale"], np.float16)
    if extra is not None and len(data["times"]):
        rot, tr, sc = extra(data, rot, tr, sc)
    for i, t in enumerate(data["times"].tolist()):
        layer.SetTimeSample(ra, t, Vt.QuatfArray.FromNumpy(np.ascontiguousarray(rot[i])))
        layer.SetTimeSample(ta, t, Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(tr[i])))
        layer.SetTimeSample(sa, t, Vt.Vec3hArray.FromNumpy(np.ascontiguousarray(sc[i])))


def _extra_joints(src, joints: list[str], rest, follower=None):
    """(every joint the animation ``src`` lists, a merge) where some are not among the
    filled ``joints`` (the skeleton lacks them, or they are under a root other than the
    character's: read.Character.anim_authored, other_joints), else None. The filled
    animation keeps them with the values ``src`` gives at each time (authored samples
    exactly, USD's interpolation between), so that it lists what the animator's does and
    changes only what the fill filled; where ``src`` never authors an attribute, ``rest(authored)``
    (read.rest_values): what the original showed. ``follower(authored)`` (:func:`_follower`):
    what moves the root controls that follow a filled joint, where the fill moved it."""
    authored = [str(t) for t in (src.GetAttribute("joints").Get() or [])] if src else []
    slot = {t: i for i, t in enumerate(authored)}
    if authored == list(joints) or any(t not in slot for t in joints):  # nothing to keep
        return None
    slots = np.array([slot[t] for t in joints], np.int64)
    attrs = [(src.GetAttribute(n), n) for n in ("rotations", "translations", "scales")]
    dtypes = (np.float32, np.float32, np.float16)
    fallback: dict = {}
    follow = follower(authored) if follower else None

    def unauthored(name: str, dtype) -> np.ndarray:
        if not fallback:  # read once, and only where an attribute is missing
            fallback.update(rest(authored))
        return fallback[name].astype(dtype)

    def at(t: float, attr, name: str, dtype) -> np.ndarray:
        v = attr.Get(t) if attr else None
        return np.array(v, dtype) if v is not None and len(v) == len(authored) else unauthored(name, dtype)

    def merge(data: dict, *filled):
        times = data["times"].tolist()
        full = [np.stack([at(t, attr, name, dtype) for t in times])
                for (attr, name), dtype in zip(attrs, dtypes, strict=True)]  # fmt: skip
        # Where the fill left the character as authored (outside its range, at keys) the
        # controls stay so too: the fill's range where the take carries it (_follower), else
        # the times where its values differ from the original's (a take of older code).
        moved = ~np.all(
            [(f[:, slots] == v).reshape(len(times), -1).all(1) for f, v in zip(full, filled, strict=True)], 0
        )
        for f, v in zip(full, filled, strict=True):
            f[:, slots] = v
        if follow is not None:
            follow(data, full, moved)
        return full

    return authored, merge


def _follower(stage, c: dict, src):
    """For :func:`_extra_joints`: given the animation's joints, what moves the kept root
    controls that follow a character joint over the keys (pipeline.usd.follow) with the
    filled joint, in a take's merged values, wherever the fill moved the character off its
    keys; None for a skeleton of one root."""
    from pipeline.usd import follow

    keys_all = np.sort(np.asarray(c["keys"], np.float64))

    def of(authored: list[str]):
        rig = follow.rig_of(stage, c["skel"], authored)
        if rig is None:
            return None
        found: dict = {}  # per set of keys: every take of one fill judges by the same keys

        def apply(data: dict, full: list, moved: np.ndarray) -> None:
            times = np.asarray(data["times"], np.float64)
            inside = data.get("inside")
            if inside is not None and len(inside):  # the fill's range, where the take carries it
                moved = (times >= np.min(inside) - follow.TIME_EPS) & (
                    times <= np.max(inside) + follow.TIME_EPS
                )
            keys = follow.fill_keys(keys_all, times, moved, inside)
            if tuple(keys) not in found:
                values = follow.values_at(src, authored, rig, keys) if len(keys) > 1 else (None,) * 3
                found[tuple(keys)] = follow.detect(rig, keys, *values)
            # The keys stay bit for bit, partial keys (whose unkeyed channels the fill moved) too.
            follow.apply(rig, found[tuple(keys)], times, *full, moved & follow.off_keys(keys_all, times))

        return apply

    return of


def _author_roots(layer, chars: list[dict], takes: list[dict]) -> None:
    """The characters' root prims: a pending review state and, for several takes, the
    ``tweenTake`` variant set (the first take selected)."""
    from pxr import Sdf

    many = len(takes) > 1
    roots = sorted({"/" + c["anim"].strip("/").split("/")[0] for c in chars})
    for r in roots:
        rs = Sdf.CreatePrimInLayer(layer, r)
        apply_api(rs, tokens.API)
        author_attr(rs, tokens.REVIEW_STATUS, Sdf.ValueTypeNames.Token, "pending")
        author_attr(rs, tokens.APPROVED_TAKE, Sdf.ValueTypeNames.Int, -1)
        if many:
            vset = Sdf.VariantSetSpec(rs, VARIANT_SET)
            for tk in takes:
                Sdf.VariantSpec(vset, f"take{tk['take']}")
            rs.SetInfo("variantSetNames", Sdf.StringListOp.Create(prependedItems=[VARIANT_SET]))
            rs.variantSelections[VARIANT_SET] = f"take{takes[0]['take']}"


def _author_provenance(spec, c: dict, meta: dict) -> None:
    """What filled the character ``c``: its model, the trust decision (and library), how its
    rig reached the model, the key pairs it jumps between."""
    from pxr import Gf, Sdf, Vt

    # Each character's own model (a rig model or the human one).
    for name, val in ((tokens.MODEL, c.get("model", meta["model"])),
                      (tokens.MODEL_HASH, c.get("model_hash", meta["model_hash"])),
                      (tokens.JOB_ID, meta["job_id"]), (tokens.CREATED_AT, meta["created_at"])):  # fmt: skip
        author_attr(spec, name, Sdf.ValueTypeNames.String, val)
    if c.get("licence"):  # under which terms its in-betweeners were made (pipeline.fill.licence)
        lic = "; ".join(f"{name}: {value}" for name, value in c["licence"].items())
        author_attr(spec, tokens.MODEL_LICENCE, Sdf.ValueTypeNames.String, lic)
    tr = c.get("trust")
    if tr:  # how far the human model was trusted against the spline, and why
        author_attr(spec, tokens.TRUST, Sdf.ValueTypeNames.Token, tr["choice"])
        author_attr(spec, tokens.TRUST_WEIGHT, Sdf.ValueTypeNames.Double, float(tr["weight"]))
        author_attr(spec, tokens.TRUST_EVIDENCE, Sdf.ValueTypeNames.String, json.dumps(tr, sort_keys=True))
        # What filled which frames: the model's share in each gap.
        _gap_attrs(spec, tr.get("gap_weights") or [], "weight", tokens.TRUST_GAPS, tokens.TRUST_GAP_WEIGHTS)
        lib = tr.get("library")
        if lib:  # the library's version, and how much of each gap is its motion
            author_attr(spec, tokens.LIBRARY, Sdf.ValueTypeNames.String, f"{lib['name']} ({lib['folder']})")
            author_attr(spec, tokens.LIBRARY_HASH, Sdf.ValueTypeNames.String, lib["hash"])
            _gap_attrs(spec, lib["gaps"], "share", tokens.LIBRARY_GAPS, tokens.LIBRARY_SHARE, even_empty=True)
    # How the rig reached the model: the reference pose and the model joints it lacks.
    rt = c.get("retarget")
    if rt:
        author_attr(spec, tokens.RETARGET_REFERENCE, Sdf.ValueTypeNames.String, rt["reference"])
        author_attr(spec, tokens.MISSING_JOINTS, Sdf.ValueTypeNames.TokenArray, Vt.TokenArray(rt["missing"]))
    if c.get("jumps"):  # key pairs the body teleports between: (from, to) time codes
        pairs = Vt.Vec2dArray([Gf.Vec2d(j["from"], j["to"]) for j in c["jumps"]])
        author_attr(spec, tokens.KEY_JUMPS, Sdf.ValueTypeNames.Double2Array, pairs)


def _copy_blend_shapes(layer, spec, src) -> None:
    """Blend shape weights are the animator's: copied from the animation ``src`` as authored."""
    from pxr import Sdf

    for an, tn in (("blendShapes", Sdf.ValueTypeNames.TokenArray), ("blendShapeWeights", None)):
        a = src.GetAttribute(an)
        if a and a.HasAuthoredValue():
            dst = author_attr(spec, an, a.GetTypeName() if tn is None else tn, uniform=an == "blendShapes")
            if a.Get() is not None:
                dst.default = a.Get()
            for t in a.GetTimeSamples():
                layer.SetTimeSample(dst.path, t, a.Get(t))


def _author_character(layer, stage, ci: int, c: dict, takes: list[dict], meta: dict) -> None:
    """Character ``ci``: its skeleton bound to a new ``<anim>_tween`` SkelAnimation holding
    the keys, the provenance and each take's samples (in its variant, for several takes)."""
    from pxr import Sdf, Vt

    from pipeline.usd.read import (
        binding_prim,
        rest_values,
    )  # here: the reader brings scipy, `tween --help` not

    many = len(takes) > 1
    src = stage.GetPrimAtPath(c["anim"])
    filled = Sdf.Path(c["anim"]).GetParentPath().AppendChild(Sdf.Path(c["anim"]).name + "_tween")
    for skel in (c["skel"], *c.get("also", ())):  # skeletons sharing the animation share its fill
        # The skeleton, or the instance it inherits its binding through (read.binding_prim).
        where = binding_prim(stage.GetRootLayer().identifier, stage.GetPrimAtPath(skel))
        sk = Sdf.CreatePrimInLayer(layer, where)
        apply_api(sk, "SkelBindingAPI")
        rel = sk.relationships.get("skel:animationSource") or Sdf.RelationshipSpec(sk, "skel:animationSource")
        rel.targetPathList.explicitItems = [filled]
    spec = Sdf.CreatePrimInLayer(layer, filled)
    spec.specifier = Sdf.SpecifierDef
    spec.typeName = "SkelAnimation"
    apply_api(spec, tokens.API)
    extra = _extra_joints(
        src, c["joints"], lambda names: rest_values(stage, c["skel"], names), _follower(stage, c, src)
    )
    joints = c["joints"] if extra is None else extra[0]
    author_attr(spec, "joints", Sdf.ValueTypeNames.TokenArray, Vt.TokenArray(joints), uniform=True)
    author_attr(spec, tokens.KEY_TIMES, Sdf.ValueTypeNames.DoubleArray, Vt.DoubleArray(c["keys"]))
    _author_provenance(spec, c, meta)
    _copy_blend_shapes(layer, spec, src)
    for tk in takes:
        data = tk["data"][ci]
        if many:
            vpath = Sdf.Path("/" + c["anim"].strip("/").split("/")[0])
            vroot = vpath.AppendVariantSelection(VARIANT_SET, f"take{tk['take']}")
            rel_path = filled.MakeRelativePath(vpath)
            vspec = Sdf.CreatePrimInLayer(layer, vroot.AppendPath(rel_path))
        else:
            vspec = spec
        author_attr(vspec, tokens.SEED, Sdf.ValueTypeNames.Int, int(tk["seed"]))
        author_attr(vspec, tokens.TAKE, Sdf.ValueTypeNames.Int, int(tk["take"]))
        _author_samples(layer, vspec, data, None if extra is None else extra[1])


def author_fill_layer(layer, stage, takes: list[dict], meta: dict) -> None:
    """Authors every character of every take into ``layer`` (an Sdf layer)."""
    from pxr import Sdf

    chars = takes[0]["chars"]
    with Sdf.ChangeBlock():
        _author_roots(layer, chars, takes)
        for ci, c in enumerate(chars):
            _author_character(layer, stage, ci, c, takes, meta)


def default_out_dir(shot: str) -> Path:
    """Beside the shot as the user gave it: a shot given through a symlink gets its layers in
    the link's folder, not in its target's."""
    return Path(os.path.abspath(shot)).parent


def _gap_attrs(
    spec, rows: list[dict], key: str, gaps_token: str, values_token: str, even_empty=False
) -> None:
    """Per gap row with key ``times`` (from, to time codes) and a value under ``key``: the
    gaps as a double2[] and their values as a double[], in one order (rows whose key frame
    has no time code are left out); nothing without rows unless ``even_empty``."""
    from pxr import Gf, Sdf, Vt

    rows = [r for r in rows if None not in r["times"]]
    if not rows and not even_empty:
        return
    author_attr(
        spec,
        gaps_token,
        Sdf.ValueTypeNames.Double2Array,
        Vt.Vec2dArray([Gf.Vec2d(*r["times"]) for r in rows]),
    )
    author_attr(
        spec, values_token, Sdf.ValueTypeNames.DoubleArray, Vt.DoubleArray([float(r[key]) for r in rows])
    )


def check_out_dir(shot: str, out_dir: str | None) -> Path:
    """The folder layers go to; raises ShotError when it cannot be written. Creates nothing."""
    out = Path(out_dir) if out_dir else default_out_dir(shot)
    probe = out
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        what = "is a file" if probe == out else f"is under {probe}, a file"
        raise ShotError(shot, f"output folder {out} {what}, not a folder (give another with --out-dir DIR)")
    # The mode bits too: a published (read-only) shot folder stays untouched even for root.
    if not writable(probe):
        raise ShotError(shot, f"output folder {out} is read-only (give another with --out-dir DIR)")
    return out


def write(shot: str, stage, takes: list[dict], meta: dict, out_dir: str | None, fmt: str,
          review_layer: str | None) -> dict:  # fmt: skip
    """Writes ``<stem>.tween.vNNN.<fmt>`` and its review root layer; returns the result dict.

    With ``meta["job_id"]`` set, a layer of that job already in the folder is returned instead
    (checked under the folder lock, so concurrent writers of one job make one layer).
    """
    if fmt not in ("usda", "usdc"):
        raise ShotError(shot, f"unknown layer format {fmt!r} (usda or usdc)")
    out = check_out_dir(shot, out_dir)
    animator = {os.path.realpath(p) for p in _layer_files(stage)}
    if review_layer and os.path.realpath(review_layer) in animator:
        raise ShotError(
            shot, f"{review_layer} is one of the shot's own layers; the animator's layers are never modified"
        )
    stem = shot_stem(shot)
    created: list[Path] = []
    try:
        with files.folder_lock(shot, out, stem, created):
            files.clean_dead_temps(out)
            if review_layer:
                files.clean_dead_temps(Path(os.path.abspath(review_layer)).parent)
            done = find_job(out, stem, meta.get("job_id", ""), shot)
            if done:
                return done
            check_series(shot, out, stem)
            return _write_locked(shot, stage, takes, meta, out, stem, fmt, review_layer)
    except BaseException:
        remove_created(created)
        raise


def _write_locked(shot, stage, takes, meta, out: Path, stem: str, fmt: str, review_layer) -> dict:
    from pxr import Sdf, UsdUtils

    src_root = stage.GetRootLayer()
    meta = dict(meta, created_at=meta.get("created_at") or datetime.datetime.now(datetime.UTC).isoformat())
    for _ in range(1000):
        n = max(taken_versions(out, stem), default=0) + 1
        final = out / f"{stem}.tween.v{n:03d}.{fmt}"
        review = Path(review_layer) if review_layer else files.review_path(out, stem, n)
        tmp = files.temp_path(final)
        with files.saving(final, tmp):
            layer = Sdf.Layer.CreateNew(str(tmp))
            if layer is None:
                raise TweenError(f"{final}: cannot write the layer")
            UsdUtils.CopyLayerMetadata(src_root, layer, True, True)
            layer.customLayerData = {
                "tween": {
                    "jobId": meta["job_id"],
                    "model": meta["model"],
                    "modelHash": meta["model_hash"],
                    "models": {c["anim"]: c.get("model", meta["model"]) for c in takes[0]["chars"]},
                    "takes": len(takes),
                    "version": n,
                    "review": review.name,
                    "shot": str(shot),
                    "createdAt": meta["created_at"],
                    **({"dna": meta["dna"]} if "dna" in meta else {}),
                    # {in-betweener: licence} of what filled the shot (pipeline.fill.licence).
                    **({"licence": dict(meta["licence"])} if meta.get("licence") else {}),
                }  # fmt: skip
            }
            author_fill_layer(layer, stage, takes, meta)
            if not layer.Save():
                raise TweenError(f"{final}: cannot write the layer")
            del layer
        if review_layer:
            with files.saving(final, tmp):
                linked = files.link_new(tmp, final)
        else:
            linked = link_version(shot, src_root, tmp, final, review)
        if linked:
            break
    else:
        raise ShotError(shot, f"could not find a free version in {out}")
    if review_layer:  # the user's layer names the fill: it goes in once the fill is there
        try:
            write_review(shot, src_root, final, review, True)
        except BaseException:
            final.unlink(missing_ok=True)
            raise
    return {"layer": str(final), "review": str(review), "version": n, "takes": len(takes),
            "model": meta["model"], "model_hash": meta["model_hash"],
            "models": {c["anim"]: c.get("model", meta["model"]) for c in takes[0]["chars"]}}  # fmt: skip


def _rel(target: Path, base_dir: Path) -> str:
    """``target`` relative to ``base_dir`` as given (a symlinked shot stays the link), or its
    absolute path where a symlinked folder on the way makes that relative path lead elsewhere.
    USD anchors a relative path at the layer's path lexically (``..`` drops a name), while the
    system follows the link: no relative path reached the shot from both the link's path of
    the layer (the one printed) and its real one, and the fill composed over nothing."""
    target, base_dir = os.path.abspath(target), os.path.abspath(base_dir)
    rel = os.path.relpath(target, base_dir)
    if os.path.realpath(os.path.join(base_dir, rel)) == os.path.realpath(target):
        return rel
    return target


def _open_review_layer(review: Path):
    """A ``--review-layer`` opened, and an empty layer of its format to edit it in; TweenError
    naming it when it is not a USD layer this can edit (.usdz cannot be)."""
    from pxr import Sdf, Tf

    from pipeline.usd.diagnostics import error_text

    try:
        layer = Sdf.Layer.FindOrOpen(str(review))
        if layer is None:
            raise TweenError(f"--review-layer {review}: cannot open as a USD layer")
        return layer, Sdf.Layer.CreateAnonymous(review.suffix)
    except Tf.ErrorException as e:
        raise TweenError(f"--review-layer {review}: cannot open as a USD layer: {error_text(e)}") from None


def check_review_layer(shot: str, stage, review_layer: str | None) -> None:
    """Before any model runs: a ``--review-layer`` must be a USD layer this can edit, in a
    folder it can write, and not one of the shot's own layers (never modified)."""
    if not review_layer:
        return
    review = Path(review_layer)
    why = _link_loop(review, "review layer") or not_a_file(review, "review layer")
    if why == "file not found":
        why = "no such file (it adds the fill to an existing root layer)"
    if why is not None:
        raise TweenError(f"--review-layer {review}: {why}")
    if os.path.realpath(review) in {os.path.realpath(p) for p in _layer_files(stage)}:
        raise ShotError(
            shot, f"{review} is one of the shot's own layers; the animator's layers are never modified"
        )
    _open_review_layer(review)
    real = Path(os.path.realpath(review))  # a link is written through: the file it names
    if not writable(real):
        raise TweenError(f"--review-layer {review}: read-only (the fill is added to a layer this may edit)")
    if not writable(real.parent):
        raise TweenError(f"--review-layer {review}: its folder {real.parent} is read-only")


def link_version(shot: str, src_root, tmp: Path, final: Path, review: Path) -> bool:
    """Makes the saved fill layer ``tmp`` the version ``final``, its review layer ``review``
    first: a process killed between the two left a fill layer without its review, which the
    next fill skipped and approve, publish and a farm job's retry took for a finished one.
    Killed now, it leaves a review layer of no fill, which every reader ignores (versions are
    the fill layers). False, and nothing made, where ``final`` is another writer's."""
    try:
        write_review(shot, src_root, final, review, False)
    except BaseException:
        files.discard(tmp)
        raise
    try:
        with files.saving(final, tmp):
            linked = files.link_new(tmp, final)
    except BaseException:
        review.unlink(missing_ok=True)
        raise
    if not linked:
        review.unlink(missing_ok=True)  # ours, made for the version another writer took
    return linked


def _strongest(sub: str, subs: list[str], anchor: Path) -> list[str]:
    """``subs`` with ``sub`` first, and no other entry naming its file: a layer that already
    listed this version (a fill since removed, its name written again) was an internal error,
    "Duplicate item not allowed for field 'subLayers'"."""

    def where(s: str) -> str:
        return os.path.normpath(os.path.join(anchor, s))

    return [sub] + [s for s in subs if where(s) != where(sub)]


def write_review(shot: str, src_root, fill: Path, review: Path, existing: bool) -> None:
    """A new review root layer [fill, shot], or the fill inserted strongest into ``review``."""
    from pxr import Sdf, UsdUtils

    if existing:
        # Through a link to the file it names (the link stays a link), keeping the file's mode;
        # one fill at a time, whatever its output folder: two read the layer, each added its
        # fill and wrote it back, and one fill was gone from it.
        real = Path(os.path.realpath(review))
        tmp = files.temp_path(real)
        lock, wait = real.parent / f".{real.name}.lock", files.LOCK_WAIT_S
        with locked(
            lock,
            timeout=wait,
            timed_out=lambda: files.lock_timed_out(lock, wait, f"another fill into {review}"),
        ):
            files.mark_holder(lock)
            layer, text = _open_review_layer(review)
            layer.Reload()  # the layer as the last writer left it, not as USD's registry holds it
            text.TransferContent(layer)
            text.subLayerPaths = _strongest(
                _rel(fill, review.parent), list(text.subLayerPaths), review.parent
            )
            with files.saving(real, tmp):
                if not text.Export(str(tmp)):
                    raise TweenError(f"{review}: cannot write the review layer")
                os.chmod(tmp, stat.S_IMODE(real.stat().st_mode))
                os.replace(tmp, real)
            layer.Reload()
        return
    tmp = files.temp_path(review)
    with files.saving(review, tmp):
        layer = Sdf.Layer.CreateNew(str(tmp))
        if layer is None:
            raise TweenError(f"{review}: cannot write the review layer")
        UsdUtils.CopyLayerMetadata(src_root, layer, True, True)
        layer.subLayerPaths = [_rel(fill, review.parent), _rel(Path(shot), review.parent)]
        layer.comment = "Review root layer written by usd-tween: the fill over the animator's shot."
        if not layer.Save():
            raise TweenError(f"{review}: cannot write the review layer")
        del layer
    with files.saving(review, tmp):
        linked = files.link_new(tmp, review)
    if not linked:
        raise ShotError(shot, f"review layer {review} already exists")


def _layer_files(stage) -> list[str]:
    out = []
    for layer in stage.GetLayerStack(includeSessionLayers=False):
        if layer.realPath:
            out.append(layer.realPath)
    for layer in stage.GetUsedLayers():
        if layer.realPath:
            out.append(layer.realPath)
    return out
