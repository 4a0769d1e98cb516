"""What the shot page shows: the takes with their turntables, the keys, what filled each gap
per character, the model, and the version history with its decisions."""

from __future__ import annotations

import glob
import json
import re
from pathlib import Path

from dailies.shots import Shot, cached, layer_info, shot_file
from render.overlays import fill_sources
from usd_schemas import tokens

TAKE_NAME = re.compile(r"take(\d+)")


def characters(path: Path) -> dict:
    """The fill layer's takes and, per filled animation, its model, keys and fill sources."""
    from pxr import Sdf, Tf

    try:
        layer = Sdf.Layer.OpenAsAnonymous(str(path))
    except Tf.ErrorException:
        layer = None
    if layer is None:
        return {"takes": [], "characters": []}
    takes: set[int] = set()
    chars, todo = [], list(layer.rootPrims)
    while todo:
        spec = todo.pop()
        vset = spec.variantSets.get(tokens.TAKE_VARIANT_SET)
        if vset is not None:
            takes |= {int(m[1]) for v in vset.variants if (m := TAKE_NAME.fullmatch(v.name))}
        if (
            spec.typeName == "SkelAnimation"
            and spec.specifier == Sdf.SpecifierDef
            and spec.name.endswith("_tween")
        ):
            chars.append(_character(spec))
        todo.extend(spec.nameChildren)
    if not takes:  # one take: no variant set, its number on the animation
        takes = {c["take"] for c in chars if c["take"] is not None} or {0}
    return {"takes": sorted(takes), "characters": sorted(chars, key=lambda c: c["path"])}


def _value(spec, name):
    a = spec.attributes.get(name)
    return None if a is None else a.default


def _character(spec) -> dict:
    facts = {}
    for key, gaps, share in (("library", tokens.LIBRARY_GAPS, tokens.LIBRARY_SHARE),
                             ("trust", tokens.TRUST_GAPS, tokens.TRUST_GAP_WEIGHTS)):  # fmt: skip
        g, w = _value(spec, gaps), _value(spec, share)
        if g is not None and w is not None:
            name = "library" if key == "library" else "trust"
            facts[f"{name}_gaps"] = [(float(a[0]), float(a[1])) for a in g]
            facts[f"{name}_gap_weights" if key == "trust" else "library_share"] = [float(x) for x in w]
    weight = _value(spec, tokens.TRUST_WEIGHT)
    take = _value(spec, tokens.TAKE)
    return {
        "path": str(spec.path.GetParentPath().AppendChild(spec.name[: -len("_tween")])),
        "model": str(_value(spec, tokens.MODEL) or ""),
        "keys": [float(k) for k in (_value(spec, tokens.KEY_TIMES) or [])],
        "trust": str(_value(spec, tokens.TRUST) or ""),
        "trust_weight": None if weight is None else float(weight),
        "library": str(_value(spec, tokens.LIBRARY) or ""),
        # (from, to, label): "model", "spline", "model 40%", "library"...
        "sources": [list(s) for s in fill_sources(facts)],
        "take": None if take is None else int(take),
    }


def history(shot: Shot) -> list[dict]:
    """Every version, newest first: a fill (its model and job) or an approval of an earlier one
    (take, who, when, note)."""
    rows = []
    for n, path in reversed(shot.versions):
        info = cached(path, layer_info) or {}
        appr = dict(info.get("approval") or {})
        rows.append({
            "version": n,
            "layer": path.name,
            "kind": "approval" if appr else "fill",
            "of": appr.get("of"),
            "model": str(info.get("model", "")),
            "job": str(info.get("jobId", "")),
            "created": str(info.get("createdAt") or appr.get("at") or ""),
            "decision": {k: appr.get(k) for k in ("status", "take", "by", "at", "note")} if appr else None,
        })  # fmt: skip
    return rows


def rendered_version(shot: Shot, n: int) -> int:
    """The fill version whose renders show version ``n``: an approval copies its fill's takes
    bit for bit, so the chain of ``approval.of`` leads to the rendered one."""
    by_name = {p.name: k for k, p in shot.versions}
    paths = dict(shot.versions)
    for _ in range(len(paths)):
        info = cached(paths[n], layer_info) or {}
        of = dict(info.get("approval") or {}).get("of")
        if not of or of not in by_name:
            return n
        n = by_name[of]
    return n


def _timeline(path: Path) -> dict:
    """Per take number, the track facts of the review timeline (JSON: no OTIO import needed)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    out = {}
    for track in (data.get("tracks") or {}).get("children", []):
        meta = dict((track.get("metadata") or {}).get("tween") or {})
        clips = [c for c in track.get("children", []) if c.get("OTIO_SCHEMA", "").startswith("Clip")]
        url = ((clips[0].get("media_reference") or {}).get("target_url") if clips else None) or ""
        n = meta.get("take_number")
        out[0 if n is None else int(n)] = {**meta, "mp4": url}
    return out


def media(shot: Shot, n: int, takes: list[int]) -> dict[int, dict]:
    """Per take: its MP4 and contact sheet (paths, None when not rendered), frame range, rate.

    The farm renders into ``<fills>/review/<stem>_vNNN[_takeN].mp4`` beside its ``.otio``; an
    approval's version shows its fill's renders, or its own where it was rendered itself."""
    src = rendered_version(shot, n)
    folder = shot.folder / "review"
    base = f"{shot.stem}_v{src:03d}"
    tracks = cached(folder / f"{base}.otio", _timeline) or {}
    out = {}
    for t in takes:
        tr = tracks.get(t, {})
        names = [tr.get("mp4")] if tr.get("mp4") else []
        names += [f"{base}_take{t}.mp4"] + ([f"{base}.mp4"] if len(takes) == 1 else [])
        if src != n:  # the approved version rendered itself (`tween review` after `tween approve`)
            names += [f"{shot.stem}_v{n:03d}_take{t}.mp4"] + (
                [f"{shot.stem}_v{n:03d}.mp4"] if len(takes) == 1 else []
            )
        mp4 = next((folder / m for m in names if m and (folder / m).is_file()), None)
        sheet = mp4.with_name(mp4.stem + "_contact.png") if mp4 else None
        rate = tr.get("rate") or [0, 1]
        out[t] = {
            "mp4": mp4,
            "contact_sheet": sheet if sheet and sheet.is_file() else None,
            "frame_range": tr.get("frame_range"),
            "fps": rate[0] / rate[1] if rate[1] else None,
            "version": src,
        }
    return out


def shot_timing(path: Path | None) -> dict:
    """The shot's time codes per second and start/end (layer metadata), for takes not rendered."""
    from pxr import Sdf, Tf

    if path is None:
        return {}
    try:
        layer = Sdf.Layer.OpenAsAnonymous(str(path), True)
    except Tf.ErrorException:
        return {}
    if layer is None:
        return {}
    out = {"fps": layer.timeCodesPerSecond if layer.HasTimeCodesPerSecond() else layer.framesPerSecond}
    if layer.HasStartTimeCode() and layer.HasEndTimeCode():
        out["frame_range"] = [layer.startTimeCode, layer.endTimeCode]
    return out


def detail(shot: Shot) -> dict:
    """Everything the shot page and ``/api/shots/KEY`` show."""
    n, path = shot.latest
    info = cached(path, layer_info) or {}
    chars = cached(path, characters) or {"takes": [], "characters": []}
    takes = chars["takes"] or [0]
    files = media(shot, n, takes)
    shot_path = shot_file(shot)
    timing = (cached(shot_path, shot_timing) if shot_path else None) or {}
    rendered = next((m for m in files.values() if m["fps"]), {})
    fps = rendered.get("fps") or timing.get("fps") or 24.0
    frame_range = rendered.get("frame_range") or timing.get("frame_range")
    keys = sorted({k for c in chars["characters"] for k in c["keys"]})
    if frame_range is None and keys:
        frame_range = [keys[0], keys[-1]]
    hist = history(shot)
    return {
        "key": shot.key,
        "stem": shot.stem,
        "folder": str(shot.folder),
        "shot": str(shot_path) if shot_path else None,
        "version": n,
        "layer": path.name,
        "status": (hist[0]["decision"] or {}).get("status") or "pending",
        "decision": hist[0]["decision"],
        "model": str(info.get("model", "")),
        "models": dict(info.get("models") or {}),
        "fps": fps,
        "frame_range": frame_range,
        "keys": keys,
        "takes": [{"take": t, **{k: v for k, v in files[t].items() if k not in ("fps",)}} for t in takes],
        "characters": chars["characters"],
        "history": hist,
        "published": sorted(p.name for p in shot.folder.glob(f"{glob.escape(shot.stem)}.publish.v*.usd*")),
    }
