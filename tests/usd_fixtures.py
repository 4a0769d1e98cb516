"""Helpers for the USD tests: real shots built from ../shared/data clips with `tween convert`."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from pipeline.data.split import shared_data_dir

DATA = shared_data_dir()
BANDAI_CLIP = DATA / "bandai_namco" / "dataset-2" / "dataset-2_walk_active_002.bvh.gz"
CMU_CLIP = DATA / "cmu_iclone" / "001_01.bvh.gz"
USD_ASSETS = DATA / "usd_assets"
ELEPHANT = USD_ASSETS / "ElephantWithMonochord" / "SoC-ElephantWithMonochord.usdc"
FIGURE = USD_ASSETS / "RiggedFigure" / "RiggedFigure.usdz"
SIMPLE = USD_ASSETS / "RiggedSimple" / "RiggedSimple.usdz"
ANIM = "/World/Character/Skel/Anim"
FILLED = "/World/Character/Skel/Anim_tween"


def bandai_shot(path: Path, frames: int = 61, keys_every: int = 10, **kw) -> Path:
    from pipeline.motion.bvh import read_bvh
    from pipeline.usd.convert import write_shot

    m = read_bvh(BANDAI_CLIP).slice(0, frames)
    write_shot(m, path, keys_every=keys_every, **kw)
    return path


def cmu_shot(path: Path, frames: int = 121, keys_every: int = 12, up_axis: str = "Z", **kw) -> Path:
    from pipeline.motion.bvh import read_bvh
    from pipeline.usd.convert import write_shot

    m = read_bvh(CMU_CLIP).slice(0, frames)
    write_shot(m, path, keys_every=keys_every, up_axis=up_axis, **kw)
    return path


def tree_hashes(folder: Path) -> dict[str, str]:
    return {
        str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def samples(stage, path: str, attr: str = "rotations") -> dict[float, np.ndarray]:
    a = stage.GetPrimAtPath(path).GetAttribute(attr)
    return {t: np.array(a.Get(t)) for t in a.GetTimeSamples()}


def tween(monkeypatch, capsys, *args) -> tuple[int, str]:
    """The `tween` entry point in this process: (exit status, stderr)."""
    import sys

    import pytest

    from pipeline.cli import main

    monkeypatch.setattr(sys, "argv", ["tween", *map(str, args)])
    with pytest.raises(SystemExit) as e:
        main()
    return e.value.code or 0, capsys.readouterr().err


def layer_samples(layer_path: Path, prim: str, attrs) -> tuple[list[str], dict[str, dict[float, np.ndarray]]]:
    """(the ``joints`` of the SkelAnimation ``prim`` in the layer at ``layer_path``, each of
    ``attrs``' time samples there by time): what a fill layer itself holds."""
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(layer_path))
    spec = layer.GetPrimAtPath(prim)
    joints = list(spec.attributes["joints"].default)
    out = {}
    for name in attrs:
        path = spec.attributes[name].path
        out[name] = {t: np.array(layer.QueryTimeSample(path, t)) for t in layer.ListTimeSamplesForPath(path)}
    return joints, out


def digest(path: Path) -> str:
    """The sha256 of one file (the user's shot, unchanged by a fill)."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def assert_kept_as_authored(written: dict, plain: dict, anim, keep: list[int], kept: list[int], keys) -> None:
    """A fill layer's samples ``written`` (:func:`layer_samples`) of the animation ``anim``
    (the animator's SkelAnimation prim), some of whose joints the fill keeps as authored: at
    every time written, the filled joints ``keep`` (indices) are bit for bit ``plain`` (the
    same fill without the kept joints), the ``kept`` ones what ``anim`` gives there; every
    joint is bit for bit at ``keys``, and the frames between keys are written."""
    for name, samples in written.items():
        assert sorted(samples) == sorted(plain[name])
        assert len([t for t in samples if keys[0] < t < keys[-1] and t not in keys]) > len(keys)
        attr = anim.GetAttribute(name)
        for t, v in samples.items():
            assert np.array_equal(v[keep], plain[name][t]), (name, t)
            assert np.array_equal(v[kept], np.array(attr.Get(t))[kept]), (name, t)
        for t in keys:
            assert np.array_equal(samples[t], np.array(attr.Get(t))), (name, t)


def add_root_joints(skel, anim, names: list[str]) -> None:
    """Adds joints ``names`` to the Skeleton prim ``skel`` as roots of their own (first in its
    joint order, identity rest and bind) and to the SkelAnimation prim ``anim``'s joint list
    (last): a rig's unparented controls, as Blender writes them. Their samples are the caller's."""
    from pxr import Gf, Vt

    skel.GetAttribute("joints").Set(Vt.TokenArray(list(names) + list(skel.GetAttribute("joints").Get())))
    for n in ("restTransforms", "bindTransforms"):
        a = skel.GetAttribute(n)
        a.Set(Vt.Matrix4dArray([Gf.Matrix4d(1)] * len(names) + list(a.Get())))
    listed = anim.GetAttribute("joints")
    listed.Set(Vt.TokenArray(list(listed.Get()) + list(names)))
