"""Filling a shot: the API the farm (``workers/``) and ``tween fill-local`` call.

``validate_shot`` checks everything before any work; ``fill_take`` computes one take into
an ``.npz`` (idempotent: same inputs → same file); ``write_layers`` writes the versioned
fill layer and the review root layer; ``fill_shot`` does all three in process.

Models per character: with ``model="default"`` a character whose skeleton fits a stored
per-rig model (``rig.json`` under the models root, :mod:`pipeline.rig.store`) is filled by
it, any other by the human model; ``model=<rig model name or folder>`` forces that rig
model, ``model=interp`` / a human model folder forces the human model (no rig models).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import tempfile
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from pipeline.errors import ShotError, TweenError

# The options are declared once in pipeline.fill.options; these names are the API's too.
from pipeline.fill.options import (  # noqa: F401
    FORMATS,
    MAX_DNA_POSES,
    MAX_SEED,
    MAX_TAKES,
    FillOptions,
    check_fill_options,
)
from pipeline.inputs import broken_link
from pipeline.library.store import open_library
from pipeline.rig.store import is_rig_folder, models_root, read_rig_json
from pipeline.usd import write
from pipeline.usd.files import clean_dead_temps, owner_tag, temp_full, write_error
from pipeline.usd.write import check_out_dir, check_shot_name

_MODELS: dict[tuple[int, str], object] = {}
#: A library fill also probes the human network (False: the library against the spline only;
#: the library bench measures both).
LIBRARY_VS_NETWORK = True
#: A human model's shipped library (model.json "library") is probed beside its network
#: (False: the network against the spline only; the benches measure both).
SHIPPED_LIBRARY = True


def _load_rig(folder: str):
    """The per-rig model in ``folder`` (its rig.json), by its kind (pipeline.infer.api)."""
    from pipeline.infer.api import RIG_FILE, load_folder

    return load_folder(folder, RIG_FILE)


def rig_folder(name: str) -> str | None:
    """The rig model folder ``name`` refers to (a folder with rig.json, or one under the
    models root), or None when it is not a rig model."""
    from pipeline.infer.api import builtin_names

    if name == "default" or name in builtin_names():
        return None
    for cand in (Path(name), models_root() / name):
        if is_rig_folder(cand):
            return str(cand.resolve())
    return None


def _model(name: str):
    """The in-betweener ``name`` (a human model, or a rig model folder), loaded once per
    process (a forked worker loads its own: onnxruntime sessions must not cross a fork), by
    the registry (pipeline.infer.api.load_model: the kind its folder declares)."""
    from pipeline.infer.api import load_model

    folder = rig_folder(name)
    key = (os.getpid(), name)
    if folder:
        # A rig model retrained in place (a new hash) is reloaded, not served stale.
        key = (os.getpid(), folder, read_rig_json(folder).hash)
    if key not in _MODELS:
        try:
            _MODELS[key] = _load_rig(folder) if folder else load_model(name)
        except FileNotFoundError as e:
            raise TweenError(f"model {name!r}: {e}") from None
        except (OSError, ValueError, RuntimeError) as e:
            if not folder:
                raise
            raise TweenError(
                f"{folder}: cannot load the rig model: {str(e).splitlines()[0] if str(e) else type(e).__name__}"
            ) from None
    return _MODELS[key]


def _library(folder: str):
    """The library in-betweener of ``folder`` (pipeline.library), loaded once per process and
    library version (a library grown with ``--add`` has a new hash and is loaded again)."""
    from pipeline.library.infer import LibraryInbetweener

    lib = open_library(folder)
    key = (os.getpid(), "library", os.path.realpath(folder), lib.hash)
    if key not in _MODELS:
        _MODELS[key] = LibraryInbetweener(lib)
    return _MODELS[key]


def _human(opts: FillOptions):
    """The human in-betweener of the job: the library with ``--library``, else the human model;
    None when a rig model is forced."""
    if rig_folder(opts.model):
        return None
    if opts.library:  # (FillOptions.check refused a --model that is no network)
        return _library(opts.library)
    return _model(opts.model)


def probed_beside(opts: FillOptions, human) -> tuple:
    """What the trusted fill probes beside the human in-betweener, the better on the shot's
    own keys deciding; with ``--trust auto`` only (otherwise nothing: what is not probed can
    fill nothing, so neither is it loaded nor does the fill name its licence). With
    ``--library``, the network ``--model`` names (the default, or a studio's fine-tune on the
    takes the library holds; LIBRARY_VS_NETWORK); else (SHIPPED_LIBRARY) the library the human
    model ships beside its network (model.json's ``"library"``), then the models it ships
    beside it (``"beside"``)."""
    if opts.trust != "auto":  # the probes decide nothing: nothing is loaded beside it
        return ()
    if opts.library:
        return (_model(opts.model),) if LIBRARY_VS_NETWORK else ()
    if not SHIPPED_LIBRARY:
        return ()
    folder = getattr(human, "library_folder", None)  # a plug-in kind may ship none
    out = (_library(str(folder)),) if folder is not None else ()
    return out + tuple(_model(str(f)) for f in getattr(human, "beside_folders", ()))


def _plan(shot: str, opts: FillOptions, human, say: bool = True):
    from pipeline.fill.plan import RIG_AUTO, RIG_OFF, make_plan

    opts.check()
    check_shot_name(str(shot))
    rig = rig_folder(opts.model) or (RIG_AUTO if opts.model == "default" else RIG_OFF)
    fps = float(human.fps) if human is not None else 30.0
    # Interpolation and the spline work on any rig, mapped or not, in its own joint space.
    own = opts.model in ("interp", "interpolation", "spline")
    return make_plan(str(shot), opts.keys, opts.range, opts.mapping, fps, rig=rig, own_rig=own, say=say)


def dna_motion(opts: FillOptions, fps: float):
    """The job's motion DNA: ``dna_poses`` representative poses of the reference take, or None."""
    if not opts.dna:
        return None

    from pipeline.infer.dna_poses import MAX_POSES, representative_frames
    from pipeline.usd.take import model_take

    if not 1 <= opts.dna_poses <= MAX_POSES:
        raise TweenError(f"dna_poses must be 1 to {MAX_POSES}, not {opts.dna_poses}")
    take = model_take(opts.dna, fps)
    idx = representative_frames(take.rotations, opts.dna_poses)
    return replace(take, rotations=take.rotations[idx], root_positions=take.root_positions[idx])


def _check_dna(opts: FillOptions, inbs: list) -> None:
    if not opts.dna:
        return
    for inb in inbs:
        if not inb.capabilities.dna:
            raise TweenError(
                f"{opts.dna}: model {inb.name} takes no motion DNA (drop --dna or pick a DNA model)"
            )


def _char_model(cp, human):
    return _model(cp.model) if cp.model else human


def _joined(values) -> str:
    return "+".join(dict.fromkeys(values))


def _licences(opts: FillOptions, cp, inb, alternatives) -> dict[str, str]:
    """{in-betweener name: its licence} of what may fill the character ``cp``: its rig model,
    or the human model, or a library and the network probed beside it (pipeline.fill.licence)."""
    from pipeline.fill.licence import folder_licence, library_licence, model_licence

    if cp.model:
        return {inb.name: folder_licence(cp.model, "rig.json")}
    # The libraries and networks the fill already opened (with --library ``inb`` is
    # ``_library``'s): nothing is read again per character.
    out = {inb.name: library_licence(inb.library.manifest) if opts.library else model_licence(opts.model)}
    for alt in alternatives:  # what is probed beside it (probed_beside)
        if alt.capabilities.per_gap:  # a library
            out[alt.name] = library_licence(alt.library.manifest)
            continue
        folder = getattr(alt, "folder", None)  # a plug-in kind may keep none: found by name
        out[alt.name] = folder_licence(folder) if folder else model_licence("default")
    return out


def merged_licences(chars: list[dict]) -> dict[str, str]:
    """{in-betweener name: licence} over the characters of a take (the fill's ``licence``)."""
    out: dict[str, str] = {}
    for c in chars:
        out.update(c.get("licence") or {})
    return out


def composition(shot: str, opts: FillOptions) -> list[str]:
    """The assets the shot names that cannot be found (pipeline.usd.read.missing_assets), one
    warning line each on stderr; with ``opts.strict`` a ShotError instead."""
    from pipeline.usd.read import missing_assets

    missing = missing_assets(shot)
    if missing and opts.strict:
        more = f" and {len(missing) - 1} more" if len(missing) > 1 else ""
        raise ShotError(shot, f"missing sublayer, reference or payload {missing[0]}{more} (--strict)")
    for asset in missing:
        # A folder, a device or a FIFO is there (missing_assets names those by absolute path).
        there = os.path.isabs(asset) and os.path.lexists(asset) and not os.path.isfile(asset)
        what = (broken_link(asset) or "not a regular file") if there else "not found"
        print(f"tween: warning: {shot}: {asset}: {what}; the shot is filled without it", file=sys.stderr)
    return missing


def warn_experimental(model: str) -> str | None:
    """Says on stderr, in one line, that ``model`` is experimental (models/README.md); returns why."""
    from pipeline.infer.folder import experimental

    why = experimental(model)
    if why:
        print(
            f"tween: warning: --model {model} is experimental ({why}); not for production shots",
            file=sys.stderr,
        )
    return why


def _decided_model(inb, decision: dict | None) -> tuple[str, str]:
    """The name and hash of the in-betweener that filled a character: where the trusted fill
    decided on one probed beside the network (a library, another network), that one's, not
    the network's it was asked for (tween:model and tween:modelHash name what filled it)."""
    source = (decision or {}).get("source")
    row = next((r for r in (decision or {}).get("candidates") or [] if r.get("name") == source), None)
    return (row["name"], row["hash"]) if row else (inb.name, inb.model_hash)


def precheck(shot: str, opts: FillOptions) -> list[str]:
    """What a farm client checks before it starts a farm or contacts a broker: the options,
    a --library's manifest, the shot's content (characters, keys, rigs: the plan, without
    loading a model) and its composition (:func:`composition`, said here), and that the
    layers' folder can be written. A ShotError/TweenError in one line, as the worker would
    give it seconds later; returns the missing assets."""
    from pipeline.infer.api import builtin_names, model_folder

    opts.check()
    if opts.model != "default" and opts.model not in builtin_names() and model_folder(opts.model) is None:
        raise TweenError(
            f"--model {opts.model}: no such model (a folder with model.json or rig.json, or the name "
            f"of one under {models_root()})"
        )
    if opts.library:  # not a library, or a damaged one: as fill-local says it
        open_library(opts.library)
    plan = _plan(shot, opts, None, say=False)
    write.check_review_layer(shot, plan.shot.stage, opts.review_layer)
    out = check_out_dir(shot, opts.out_dir)  # a read-only output folder, before any farm starts
    write.check_series(shot, out, write.shot_stem(shot))
    plan.say()
    warn_experimental(opts.model)
    return composition(shot, opts)


def validate_shot(shot: str, opts: FillOptions) -> dict:
    """Raises ShotError on bad input; returns a JSON-safe summary of what will be filled,
    with the model of each character under ``models`` and the assets it names that are
    missing under ``missing_assets``."""
    return _validate(shot, opts)[0]


def _validate(shot: str, opts: FillOptions):
    """:func:`validate_shot`'s summary, and the plan it checked (for the takes of this process)."""
    opts.check()  # before any model is loaded
    from pipeline.infer.folder import ort_threads

    ort_threads()  # a bad TWEEN_ORT_THREADS before the plan is said (one line on a refusal)
    human = _human(opts)
    plan = _plan(shot, opts, human, say=False)
    write.check_review_layer(shot, plan.shot.stage, opts.review_layer)
    out_dir = check_out_dir(shot, opts.out_dir)
    write.check_series(shot, out_dir, write.shot_stem(shot))
    plan.say()  # every check of the shot passed: one line on a refusal
    summary = plan.summary()
    summary["missing_assets"] = composition(shot, opts)
    summary["out_dir"] = str(out_dir)
    models = {}
    inbs = [_char_model(cp, human) for cp in plan.chars]
    alternatives = probed_beside(opts, human)
    for cp, inb in zip(plan.chars, inbs, strict=True):
        models[cp.char.anim_path] = {
            "name": inb.name,
            "hash": inb.model_hash,
            "kind": "rig" if cp.model else "human",
            **({"folder": cp.model} if cp.model else {}),
            "licence": _licences(opts, cp, inb, alternatives if cp.model is None else ()),
        }
    _check_dna(opts, inbs)
    dna = dna_motion(opts, float(inbs[0].fps))
    if dna is not None:
        summary["dna"] = {"file": opts.dna, "poses": len(dna)}
    summary.update(
        model=_joined(m["name"] for m in models.values()),
        model_hash=_joined(m["hash"] for m in models.values()),
        models=models,
    )
    for anim, m in models.items():
        human = m["kind"] == "human"
        names = [a.name for a in alternatives] if human else []  # probed_beside: --trust auto only
        what = m["name"] if opts.library and human else f"{m['kind']} model {m['name']}"
        net = "the human network " if opts.library else ""
        beside = f", with {net}{' and '.join(names)} probed beside it" if names else ""
        print(f"tween: {shot} {anim}: {what}{beside}", file=sys.stderr)
    return summary, plan


def trust_line(d: dict) -> str:
    """One line for people of a trust decision (pipeline.infer.trust.TrustDecision.to_json)."""
    line = f"trust {d['choice']} (model weight {d['weight']:.2f}"
    if d.get("model_error_cm") is not None:
        line += (f"; at {len(d.get('probes') or [])} probe(s) of the shot's own keys the model is "
                 f"{d['model_error_cm']:.2f} cm off, the spline {d['spline_error_cm']:.2f} cm")  # fmt: skip
    if d.get("novelty_cm") is not None:
        line += (
            f"; keys {d['novelty_cm']:.1f} cm from its training poses (familiarity {d['familiarity']:.2f})"
        )
    if d.get("familiar_credit") is False:  # a studio's fine-tune (model.json): familiarity counted 0
        line += "; no familiar credit (model.json): its probes alone decide"
    if d.get("source") and len(d.get("candidates") or []) > 1:
        line += f"; decided on {d['source']} by the probes"
    lib = d.get("library")
    if lib:
        gaps = lib["gaps"]
        used = [g for g in gaps if g["weight"] > 0]
        miss = [g["miss_cm"] for g in used]
        line += f"; library {lib['name']}: {len(used)} of {len(gaps)} gap(s) from its takes"
        if miss:
            line += f" (median miss at the keys {float(np.median(miss)):.1f} cm)"
        if len(used) < len(gaps):
            line += f", {len(gaps) - len(used)} the spline's"
    return line + ")"


def _fill_identity(inb) -> str:
    """What of a model decides its fills beyond its hash: its pose bank (the trusted fill's
    decisions)."""
    out = inb.model_hash
    if inb.capabilities.novelty:
        out += "+bank:" + hashlib.sha256(np.ascontiguousarray(inb.pose_bank).tobytes()).hexdigest()[:12]
    return out


def _digest(shot: str, stage, opts: FillOptions, take: int, model_hash) -> str:
    """Hash of every layer file the shot uses, the options that change values, the take, and
    the model hash of every character's model."""
    h = hashlib.sha256()
    for path in sorted({layer.realPath for layer in stage.GetUsedLayers() if layer.realPath}):
        h.update(path.encode())
        h.update(Path(path).read_bytes())
    if opts.mapping:
        h.update(Path(opts.mapping).read_bytes())
    if opts.dna:
        h.update(Path(opts.dna).read_bytes())
    d = {k: v for k, v in asdict(opts).items() if k in ("keys", "range", "seed", "model", "mapping", "trust")}
    if opts.dna:  # takes without a DNA keep the digests they had
        d.update(dna=opts.dna, dna_poses=opts.dna_poses)
    if opts.library:  # its content is in the model hash (library-<hash>)
        d.update(library=os.path.realpath(opts.library))
    h.update(json.dumps([os.path.realpath(shot), d, take, model_hash], sort_keys=True).encode())
    return h.hexdigest()[:16]


def fill_take(shot: str, opts: FillOptions, take: int, work_dir: str, plan=None, on_character=None) -> str:
    """Fills every character for take ``take`` (seed = opts.seed + take) into an .npz.
    ``plan``: the one :func:`fill_shot` validated (default: the shot read again, as a farm
    task that runs alone reads it). ``on_character(i)``: called as character ``i`` is filled
    (fill_shot's progress; a farm task passes none and says nothing more)."""
    from pipeline.fill.solve import fill_character

    human = _human(opts)
    if plan is None:
        plan = _plan(shot, opts, human, say=False)  # validate_shot said its notes, once
    inbs = [_char_model(cp, human) for cp in plan.chars]
    _check_dna(opts, inbs)
    # A human character is also probed with what ships or is asked beside it (the better decides).
    alternatives = probed_beside(opts, human)
    try:
        identity = [_fill_identity(m) for m in (*inbs, *alternatives)]
        digest = _digest(shot, plan.shot.stage, opts, take, identity)
    except OSError as e:
        raise ShotError(shot, f"cannot read: {e.strerror}") from None
    out = Path(work_dir) / f"{Path(shot).name.split('.')[0]}.take{take:03d}.{digest}.npz"
    if out.exists():
        return str(out)
    arrays: dict[str, np.ndarray] = {}
    chars = []
    dna = dna_motion(opts, float(inbs[0].fps))
    for i, (cp, inb) in enumerate(zip(plan.chars, inbs, strict=True)):
        data = fill_character(plan, cp, inb, seed=opts.seed + take, dna=dna, trust=opts.trust,
                              alternatives=alternatives if cp.model is None else ())  # fmt: skip
        decision = data.pop("trust")
        if decision is not None and take == 0:
            print(f"tween: {shot} {cp.char.anim_path}: {trust_line(decision)}", file=sys.stderr)
        for k, v in data.items():
            arrays[f"c{i}_{k}"] = v
        if on_character is not None:
            on_character(i)
        c = cp.char
        name, model_hash = _decided_model(inb, decision)
        chars.append({"anim": c.anim_path, "skel": c.skel_path, "also": cp.also, "joints": list(c.anim_joints),
                      "keys": [float(x) for x in cp.keys], "model": name, "model_hash": model_hash,
                      "model_kind": "rig" if cp.model else "human",
                      "licence": _licences(opts, cp, inb, alternatives if cp.model is None else ()),
                      "retarget": cp.retarget_info(), "trust": decision, "jumps": cp.jumps})  # fmt: skip
    meta = {"shot": os.path.realpath(shot), "take": take, "seed": opts.seed + take,
            "model": _joined(m.name for m in inbs), "model_hash": _joined(m.model_hash for m in inbs),
            "chars": chars}  # fmt: skip
    if dna is not None:
        meta["dna"] = {"file": os.path.realpath(opts.dna), "poses": len(dna)}
    arrays["meta"] = np.array(json.dumps(meta))
    _save_take(out, arrays)
    return str(out)


def _save_take(out: Path, arrays: dict) -> None:
    """Writes the take atomically (a temp named after this process, then a rename); a full
    disk is one line naming the take; the temps of dead writers in the folder go first."""

    tmp = None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        clean_dead_temps(out.parent, quiet=True)
        fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=f".{out.name}.{owner_tag()}.", suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, out)
    except OSError as e:
        err = write_error(out, e)
        if err is not None:
            raise err from None
        raise
    finally:
        if tmp and os.path.exists(tmp):
            os.unlink(tmp)


def load_take(path: str) -> dict:
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        # "inside": the times the fill filled (its range), which the writer's following
        # controls judge by (pipeline.usd.follow); a take written before it carried them has none.
        data = [
            {
                k: z[f"c{i}_{k}"]
                for k in ("times", "rot", "trans", "scale", "keys", "inside")
                if f"c{i}_{k}" in z
            }
            for i in range(len(meta["chars"]))
        ]
    return dict(meta, data=data)


def write_layers(shot: str, opts: FillOptions, take_files: list[str], job_id: str = "") -> dict:
    """Writes the versioned fill layer (+ tweenTake variants when takes > 1) and the review
    root layer; returns {"layer", "review", "version", "takes", "model", "model_hash", ...},
    with "experimental" where the model is (:func:`outcome`). Idempotent per ``job_id``."""
    from pipeline.usd.read import open_stage

    out_dir = Path(opts.out_dir) if opts.out_dir else write.default_out_dir(shot)
    if job_id and out_dir.is_dir():  # a fast path; write.write checks again under the folder lock
        done = write.find_job(out_dir, write.shot_stem(shot), job_id, shot)
        if done:
            # A task delivered again after it wrote: the same layer, and what its takes say
            # (decisions, identical takes) as the first delivery returned them.
            if take_files and all(os.path.exists(p) for p in take_files):
                return {**done, **outcome(shot, opts, _load_takes(shot, take_files))}
            return done
    takes = _load_takes(shot, take_files)
    stage = open_stage(shot)
    meta = {"model": takes[0]["model"], "model_hash": takes[0]["model_hash"], "job_id": job_id}
    if "dna" in takes[0]:
        meta["dna"] = takes[0]["dna"]
    said = outcome(shot, opts, takes)
    meta["licence"] = said["licence"]
    result = write.write(shot, stage, takes, meta, opts.out_dir, opts.fmt, opts.review_layer)
    return {**result, **said}


def _load_takes(shot: str, take_files: list[str]) -> list[dict]:
    """The take files, in take order, checked to be of this shot and its characters."""
    if not take_files:
        raise ShotError(shot, "no takes to write")
    takes = sorted((load_take(p) for p in take_files), key=lambda t: t["take"])
    for t in takes:
        if t["shot"] != os.path.realpath(shot):
            raise ShotError(shot, f"take file {t['shot']} was filled from another shot")
        if [c["anim"] for c in t["chars"]] != [c["anim"] for c in takes[0]["chars"]]:
            raise ShotError(shot, "take files disagree on the shot's characters")
    return takes


def outcome(shot: str, opts: FillOptions, takes: list[dict]) -> dict:
    """What the fill's JSON says beside the layers it wrote: licences, decisions, jumps, missing
    assets, identical takes and an experimental model's reason."""
    from pipeline.infer.folder import experimental
    from pipeline.usd.read import missing_assets

    # Under which terms each in-betweener that filled the shot was made (pipeline.fill.licence).
    result = {"licence": merged_licences(takes[0]["chars"])}
    # Per character: how far the human model was trusted against the spline (None: not asked).
    result["trust"] = {c["anim"]: c.get("trust") for c in takes[0]["chars"]}
    # Per character: the key pairs its body teleports between (pipeline.fill.jumps).
    result["jumps"] = {c["anim"]: c.get("jumps", []) for c in takes[0]["chars"]}
    # The sublayers, references and payloads the shot names that could not be found.
    result["missing_assets"] = missing_assets(shot)
    # Takes that came out bit-identical to an earlier one (the trusted fill decided for the
    # spline, which has no seed): said once and rendered once.
    result["same_as"] = same_takes(takes)
    # Why the model is experimental (models/README.md), in every fill's JSON: fill-local's and
    # the farm's, whose result is this stage's; the farm client says it on stderr.
    why = experimental(opts.model)
    if why:
        result["experimental"] = why
    return result


def same_takes(takes: list[dict]) -> dict[str, int]:
    """{take: the earlier take it equals bit for bit} (str keys: it travels as JSON), for
    takes as :func:`load_take` reads them (in take order)."""
    out: dict[str, int] = {}
    for i, t in enumerate(takes):
        for j in range(i):
            if str(j) in out:
                continue
            a, b = t["data"], takes[j]["data"]
            if all(
                np.array_equal(x[k], y[k])
                for x, y in zip(a, b, strict=True)
                for k in ("rot", "trans", "scale")
            ):
                out[str(t["take"])] = int(takes[j]["take"])
                break
    return out


def fill_shot(shot: str, opts: FillOptions, job_id: str = "", on_progress=None) -> dict:
    """Validate, fill every take and write, in this process.

    The takes go to a folder of the system temp folder named after this process
    (``tween-take.<pid>@<host>.<rand>.tmp``); those of runs that died are removed first.
    ``on_progress(done, total, what)``: the steps (takes × characters, then the layers) done
    and what runs next; first called once the shot is validated, so a refused shot reports
    nothing (``tween fill-local`` draws its bar from it).
    """

    # One plan for every take: a plan per take read (and checked) every sample of the shot
    # again for each take; held to the end, it also keeps the shot's layers open (not parsed
    # again) for the writer.
    summary, plan = _validate(shot, opts)
    warn_experimental(opts.model)  # write_layers puts it in the JSON
    base = tempfile.gettempdir()
    clean_dead_temps(base, quiet=True)
    try:
        work = tempfile.mkdtemp(prefix=f"tween-take.{owner_tag()}.", suffix=".tmp", dir=base)
    except OSError as e:
        raise write_error(base, e) or e from None
    try:
        with temp_full(f"filling the takes of {shot}"):  # not the layers: a full shot folder is its own line
            files = _fill_takes(shot, opts, work, plan, on_progress or _quiet)
        result = write_layers(shot, opts, files, job_id)
        steps = opts.takes * len(plan.chars) + 1
        (on_progress or _quiet)(steps, steps, "")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    result["characters"] = summary["characters"]
    result["skeletons"] = summary["skeletons"]  # per animation: the skeletons its fill is bound to
    result["retarget"] = summary["retarget"]  # per character: reference pose, joints the rig lacks
    return result


def _quiet(done: int, total: int, what: str) -> None:
    """A fill_shot that nobody follows (the API's, the tests')."""


def _fill_takes(shot: str, opts: FillOptions, work: str, plan, on_progress) -> list[str]:
    """Every take of ``plan`` into ``work``, saying each step to ``on_progress`` (see fill_shot):
    a take already in ``work`` (the same digest) counts as done whole."""
    n = len(plan.chars)
    total = opts.takes * n + 1  # the layers are the last step
    anims = [cp.char.anim_path for cp in plan.chars]

    def what(t: int, i: int) -> str:
        if t >= opts.takes:
            return "writing the layers"
        return f"take {t + 1}/{opts.takes} {anims[i]}" if opts.takes > 1 else anims[i]

    on_progress(0, total, what(0, 0))
    files = []
    for t in range(opts.takes):

        def said(i: int, t: int = t) -> None:
            done = t * n + i + 1
            on_progress(done, total, what(*divmod(done, n)))

        files.append(fill_take(shot, opts, t, work, plan, on_character=said))
        on_progress((t + 1) * n, total, what(t + 1, 0))
    return files
