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
import os
import re
from pathlib import Path

import numpy as np

import pipeline.usd  # noqa: F401
from pipeline.errors import ShotError

VARIANT_SET = "tweenTake"


def shot_stem(shot: str) -> str:
    return Path(shot).name.split(".")[0]


def _versions(out_dir: Path, stem: str) -> dict[int, Path]:
    pat = re.compile(rf"^{re.escape(stem)}\.tween\.v(\d+)\.usd[ac]?$")
    out = {}
    for p in out_dir.glob(f"{stem}.tween.v*.usd*"):
        m = pat.match(p.name)
        if m:
            out[int(m.group(1))] = p
    return out


def find_job(out_dir: Path, stem: str, job_id: str) -> dict | None:
    """The result of a layer in ``out_dir`` already written by ``job_id``, if any."""
    from pxr import Sdf

    if not job_id:
        return None
    for n, p in sorted(_versions(out_dir, stem).items()):
        layer = Sdf.Layer.OpenAsAnonymous(str(p))
        info = dict(layer.customLayerData.get("tween", {})) if layer else {}
        if info.get("jobId") == job_id:
            return {
                "layer": str(p),
                "review": str(out_dir / info.get("review", "")),
                "version": n,
                "takes": int(info.get("takes", 1)),
                "model": info.get("model", ""),
                "model_hash": info.get("modelHash", ""),
                "models": dict(info.get("models", {})),
            }
    return None


def _apply_api(spec, name: str) -> None:
    from pxr import Sdf

    spec.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=[name]))


def _attr(spec, name, type_name, value=None, uniform=False):
    from pxr import Sdf

    a = spec.attributes.get(name) or Sdf.AttributeSpec(
        spec, name, type_name, Sdf.VariabilityUniform if uniform else Sdf.VariabilityVarying
    )
    if value is not None:
        a.default = value
    return a


def _author_samples(layer, spec, data: dict) -> None:
    from pxr import Sdf, Vt

    ra = _attr(spec, "rotations", Sdf.ValueTypeNames.QuatfArray).path
    ta = _attr(spec, "translations", Sdf.ValueTypeNames.Float3Array).path
    sa = _attr(spec, "scales", Sdf.ValueTypeNames.Half3Array).path
    rot = np.ascontiguousarray(data["rot"], np.float32)
    tr = np.ascontiguousarray(data["trans"], np.float32)
    sc = np.ascontiguousarray(data["scale"], np.float16)
    for i, t in enumerate(data["times"].tolist()):
        layer.SetTimeSample(ra, t, Vt.QuatfArray.FromNumpy(rot[i]))
        layer.SetTimeSample(ta, t, Vt.Vec3fArray.FromNumpy(tr[i]))
        layer.SetTimeSample(sa, t, Vt.Vec3hArray.FromNumpy(sc[i]))


def author_fill_layer(layer, stage, takes: list[dict], meta: dict) -> None:
    """Authors every character of every take into ``layer`` (an Sdf layer)."""
    from pxr import Sdf, Vt

    chars = takes[0]["chars"]
    many = len(takes) > 1
    with Sdf.ChangeBlock():
        roots = sorted({"/" + c["anim"].strip("/").split("/")[0] for c in chars})
        for r in roots:
            rs = Sdf.CreatePrimInLayer(layer, r)
            _apply_api(rs, "TweenAPI")
            _attr(rs, "tween:reviewStatus", Sdf.ValueTypeNames.Token, "pending")
            _attr(rs, "tween:approvedTake", Sdf.ValueTypeNames.Int, -1)
            if many:
                vset = Sdf.VariantSetSpec(rs, VARIANT_SET)
                for tk in takes:
                    Sdf.VariantSpec(vset, f"take{tk['take']}")
                rs.SetInfo("variantSetNames", Sdf.StringListOp.Create(prependedItems=[VARIANT_SET]))
                rs.variantSelections[VARIANT_SET] = f"take{takes[0]['take']}"
        for ci, c in enumerate(chars):
            src = stage.GetPrimAtPath(c["anim"])
            filled = Sdf.Path(c["anim"]).GetParentPath().AppendChild(Sdf.Path(c["anim"]).name + "_tween")
            sk = Sdf.CreatePrimInLayer(layer, c["skel"])
            _apply_api(sk, "SkelBindingAPI")
            rel = sk.relationships.get("skel:animationSource") or Sdf.RelationshipSpec(
                sk, "skel:animationSource"
            )
            rel.targetPathList.explicitItems = [filled]
            spec = Sdf.CreatePrimInLayer(layer, filled)
            spec.specifier = Sdf.SpecifierDef
            spec.typeName = "SkelAnimation"
            _apply_api(spec, "TweenAPI")
            _attr(spec, "joints", Sdf.ValueTypeNames.TokenArray, Vt.TokenArray(c["joints"]), uniform=True)
            _attr(spec, "tween:keyTimes", Sdf.ValueTypeNames.DoubleArray, Vt.DoubleArray(c["keys"]))
            # Each character's own model (a rig model or the human one).
            for name, val in (("model", c.get("model", meta["model"])),
                              ("modelHash", c.get("model_hash", meta["model_hash"])),
                              ("jobId", meta["job_id"]), ("createdAt", meta["created_at"])):  # fmt: skip
                _attr(spec, f"tween:{name}", Sdf.ValueTypeNames.String, val)
            # How the rig reached the model: the reference pose and the model joints it lacks.
            rt = c.get("retarget")
            if rt:
                _attr(spec, "tween:retargetReference", Sdf.ValueTypeNames.String, rt["reference"])
                _attr(
                    spec, "tween:missingJoints", Sdf.ValueTypeNames.TokenArray, Vt.TokenArray(rt["missing"])
                )
            # Blend shape weights are the animator's: copied as authored.
            for an, tn in (("blendShapes", Sdf.ValueTypeNames.TokenArray), ("blendShapeWeights", None)):
                a = src.GetAttribute(an)
                if a and a.HasAuthoredValue():
                    dst = _attr(spec, an, a.GetTypeName() if tn is None else tn, uniform=an == "blendShapes")
                    if a.Get() is not None:
                        dst.default = a.Get()
                    for t in a.GetTimeSamples():
                        layer.SetTimeSample(dst.path, t, a.Get(t))
            for tk in takes:
                data = tk["data"][ci]
                if many:
                    vpath = Sdf.Path("/" + c["anim"].strip("/").split("/")[0])
                    vroot = vpath.AppendVariantSelection(VARIANT_SET, f"take{tk['take']}")
                    rel_path = filled.MakeRelativePath(vpath)
                    vspec = Sdf.CreatePrimInLayer(layer, vroot.AppendPath(rel_path))
                else:
                    vspec = spec
                _attr(vspec, "tween:seed", Sdf.ValueTypeNames.Int, int(tk["seed"]))
                _attr(vspec, "tween:take", Sdf.ValueTypeNames.Int, int(tk["take"]))
                _author_samples(layer, vspec, data)


def _link_new(tmp: Path, final: Path) -> bool:
    """Moves tmp to final only if final does not exist (atomic, never overwrites)."""
    try:
        os.link(tmp, final)
    except FileExistsError:
        return False
    finally:
        tmp.unlink(missing_ok=True)
    return True


def check_out_dir(shot: str, out_dir: str | None) -> Path:
    """The folder layers go to; raises ShotError when it cannot be written."""
    out = Path(out_dir) if out_dir else Path(shot).resolve().parent
    probe = out
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    # The mode bits too: a published (read-only) shot folder stays untouched even for root.
    if not probe.is_dir() or not os.access(probe, os.W_OK) or not probe.stat().st_mode & 0o222:
        raise ShotError(shot, f"output folder {out} is read-only (use --out DIR)")
    return out


def write(shot: str, stage, takes: list[dict], meta: dict, out_dir: str | None, fmt: str,
          review_layer: str | None) -> dict:  # fmt: skip
    """Writes ``<stem>.tween.vNNN.<fmt>`` and its review root layer; returns the result dict."""
    from pxr import Sdf, UsdUtils

    if fmt not in ("usda", "usdc"):
        raise ShotError(shot, f"unknown layer format {fmt!r} (usda or usdc)")
    out = check_out_dir(shot, out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ShotError(shot, f"cannot create output folder {out}: {e.strerror}") from None
    animator = {os.path.realpath(p) for p in _layer_files(stage)}
    if review_layer and os.path.realpath(review_layer) in animator:
        raise ShotError(
            shot, f"{review_layer} is one of the shot's own layers; the animator's layers are never modified"
        )
    stem = shot_stem(shot)
    src_root = stage.GetRootLayer()
    meta = dict(meta, created_at=meta.get("created_at") or datetime.datetime.now(datetime.UTC).isoformat())
    for _ in range(1000):
        taken = set(_versions(out, stem)) | {
            int(m.group(1))
            for p in out.glob(f"{stem}.review.v*.usd*")
            if (m := re.search(r"\.v(\d+)\.", p.name))
        }
        n = max(taken, default=0) + 1
        final = out / f"{stem}.tween.v{n:03d}.{fmt}"
        review = Path(review_layer) if review_layer else out / f"{stem}.review.v{n:03d}.usda"
        tmp = out / f".{stem}.tween.v{n:03d}.{os.getpid()}.tmp.{fmt}"
        layer = Sdf.Layer.CreateNew(str(tmp))
        try:
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
                }  # fmt: skip
            }
            author_fill_layer(layer, stage, takes, meta)
            layer.Save()
        except Exception:
            tmp.unlink(missing_ok=True)
            raise
        if _link_new(tmp, final):
            break
    else:
        raise ShotError(shot, f"could not find a free version in {out}")
    try:
        _write_review(shot, src_root, final, review, bool(review_layer))
    except Exception:
        final.unlink(missing_ok=True)
        raise
    return {"layer": str(final), "review": str(review), "version": n, "takes": len(takes),
            "model": meta["model"], "model_hash": meta["model_hash"],
            "models": {c["anim"]: c.get("model", meta["model"]) for c in takes[0]["chars"]}}  # fmt: skip


def _rel(target: Path, base_dir: Path) -> str:
    return os.path.relpath(os.path.realpath(target), os.path.realpath(base_dir))


def _write_review(shot: str, src_root, fill: Path, review: Path, existing: bool) -> None:
    """A new review root layer [fill, shot], or the fill inserted strongest into ``review``."""
    from pxr import Sdf, UsdUtils

    tmp = review.with_name(f".{review.stem}.{os.getpid()}.tmp{review.suffix}")
    if existing:
        layer = Sdf.Layer.FindOrOpen(str(review))
        if layer is None:
            raise ShotError(shot, f"review layer {review} cannot be opened")
        text = Sdf.Layer.CreateAnonymous(review.suffix)
        text.TransferContent(layer)
        subs = list(text.subLayerPaths)
        subs.insert(0, _rel(fill, review.parent))
        text.subLayerPaths = subs
        text.Export(str(tmp))
        os.replace(tmp, review)
        layer.Reload()
        return
    layer = Sdf.Layer.CreateNew(str(tmp))
    UsdUtils.CopyLayerMetadata(src_root, layer, True, True)
    layer.subLayerPaths = [_rel(fill, review.parent), _rel(Path(shot), review.parent)]
    layer.comment = "Review root layer written by usd-tween: the fill over the animator's shot."
    layer.Save()
    if not _link_new(tmp, review):
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
