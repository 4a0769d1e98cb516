"""Skeletons of several roots and animations listing joints their skeleton lacks, generated
(Hypothesis), through the real reader and writer.

1. ``read.character_joints`` on generated joint lists UsdSkel accepts (1-4 roots, random
   sizes, sometimes a joint under a path the list leaves out) against a path-prefix oracle
   written here: one root is (None, None); several are the strictly largest root's subtree
   in skeleton order, closed under parents, or a refusal exactly when the two largest tie or
   a joint's parent path is not listed.
2. ``tween fill-local --model interp|spline`` on the example walk with extra root
   hierarchies (a tie, a larger one, one with a joint under an unlisted path), joints of no
   skeleton in the animation, the walk's joints reordered or fewer, random values, extra
   sample times, an attribute with one value or none, a second skeleton sharing the
   animation: a refusal (one line, nothing written) exactly when the oracle refuses; else
   the fill lists the animation's joints as authored, keeps the joints it does not fill at
   the values the animator's animation gives at every time it writes, keeps every key bit
   for bit, fills the walk bit for bit as without the extras, and leaves the shot untouched.

``TWEEN_HYPOTHESIS_EXAMPLES`` scales the example counts (``make test-nightly``).
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from usd_fixtures import digest, layer_samples, tween

SHOT = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"
SKEL = "/World/Walker/Skel"
ANIM = f"{SKEL}/Anim"
FILLED = f"{SKEL}/Anim_tween"
ATTRS = ("rotations", "translations", "scales")
UNAUTHORED = {"rotations": (0, 0, 0, 1), "translations": (0, 0, 0), "scales": (1, 1, 1)}
SCALE = int(os.environ.get("TWEEN_HYPOTHESIS_EXAMPLES", "200")) / 200  # make test-nightly: more
TOPOLOGY_EXAMPLES = max(1, int(300 * SCALE))
FILL_EXAMPLES = max(1, int(150 * SCALE))

names = st.from_regex(r"[A-Za-z][A-Za-z0-9_]{0,5}", fullmatch=True)


# ------------------------------------------------------------------ 1. character_joints


@st.composite
def joint_lists(draw) -> list[str]:
    """Joint paths UsdSkel accepts (each parent listed before its children): 1-4 trees of
    1-6 joints, sometimes a joint left out of the list (its children hang under the nearest
    listed ancestor) or a root under a group path the list does not hold."""
    paths: list[str] = []
    for r in range(draw(st.integers(1, 4))):
        root = f"R{r}{draw(names)}"
        if draw(st.integers(0, 9)) == 0:
            root = f"Grp/{root}"
        tree = [root]
        for k in range(draw(st.integers(0, 5))):
            tree.append(f"{draw(st.sampled_from(tree))}/j{k}")
        if len(tree) > 1 and draw(st.integers(0, 5)) == 0:  # a joint renamed or removed
            tree.remove(draw(st.sampled_from(tree[1:])))
        paths.append(tree)
    out: list[str] = []
    while any(paths):  # a random interleaving of the trees: each keeps parents first
        out.append(draw(st.sampled_from([t for t in paths if t])).pop(0))
    return out


def _oracle(joints: list[str]):
    """("one root" | words of the refusal | the expected indices) from the paths alone."""
    listed = set(joints)

    def ancestors(t):
        parts = t.split("/")
        return ["/".join(parts[:i]) for i in range(len(parts) - 1, 0, -1)]

    roots = [t for t in joints if not any(a in listed for a in ancestors(t))]
    if len(roots) < 2:
        return "one root"
    if any(t.rpartition("/")[0] and t.rpartition("/")[0] not in listed for t in joints):
        return "which the skeleton does not list"
    under = {r: [i for i, t in enumerate(joints) if t == r or t.startswith(r + "/")] for r in roots}
    sizes = sorted((len(v) for v in under.values()), reverse=True)
    if sizes[0] == sizes[1]:
        return f"each hold {sizes[0]} joints"
    return max(under.values(), key=len)


@settings(max_examples=TOPOLOGY_EXAMPLES, deadline=None, database=None)
@given(joint_lists())
def test_character_joints_is_the_strictly_largest_hierarchy_or_a_refusal(joints):
    from pxr import UsdSkel, Vt

    from pipeline.usd.read import character_joints

    topology = UsdSkel.Topology(Vt.TokenArray(joints))
    assert topology.Validate()[0], joints
    parents = list(topology.GetParentIndices())
    main, why = character_joints(joints, parents)
    expected = _oracle(joints)
    if expected == "one root":
        assert (main, why) == (None, None), joints
        return
    if isinstance(expected, str):  # refused: the roots, and why
        n = sum(p < 0 for p in parents)
        assert main is None and why and why.startswith(f"{n} root joints ("), (joints, why)
        assert expected in why, (joints, why)
        return
    assert why is None, (joints, why)
    got = [int(i) for i in main]
    assert got == expected, joints  # the subtree, in skeleton order
    root = got[0]
    assert parents[root] < 0 and all(parents[i] in got for i in got if i != root), joints


# ------------------------------------------------------------------ 2. a fill round trip


@dataclass
class Case:
    """What one example makes of the example walk."""

    roots: list[list[str]] = field(default_factory=list)  # extra root hierarchies, parents first
    skel_order: list[bool] = field(default_factory=list)  # interleaving: True takes an extra joint
    base: list[int] = field(default_factory=list)  # the walk's animation joints kept, in this order
    anim_extra: list[str] = field(default_factory=list)  # joints the animation lists in addition
    anim_order: list[bool] = field(default_factory=list)
    modes: dict[str, str] = field(default_factory=dict)  # per attribute: keep, more, none
    new_times: list[float] = field(default_factory=list)
    seed: int = 0
    expect: str = "fill"  # or "refused", or "refused late" (by fill.plan, once the shot is read)
    character: str = "Hips"  # the root of the hierarchy that is filled
    second: list[list[str]] | None = None  # a second skeleton on the animation: its extra roots
    second_order: list[bool] = field(default_factory=list)
    second_hips: list[int] = field(default_factory=list)  # its order of the walk's joints
    second_rest: tuple[int, str] | None = None  # a walk joint whose rest differs there: how
    model: str = "interp"


BAD_TOKENS = ["bad name", "/Abs/Path", "a//b", "Hips/", "1x"]  # no relative prim path


@st.composite
def cases(draw, hips: tuple[str, ...]) -> Case:
    """Extra root hierarchies (:func:`_extra_roots`), sometimes a second skeleton on the
    animation (:func:`_second`), some joints of no skeleton in the animation, random places;
    the walk's own joints sometimes reordered or fewer; rarely a token that is no joint path
    or a joint listed twice; what each attribute's samples become."""
    c = Case()
    taken = set(hips)
    animated = _extra_roots(draw, c, hips, taken)
    if draw(st.integers(0, 3)) == 0:
        animated += _second(draw, c, hips)
    extra_skel = [t for tree in c.roots for t in tree]
    c.skel_order = draw(st.permutations([False] * len(hips) + [True] * len(extra_skel)))
    c.base = list(range(len(hips)))
    how = draw(st.sampled_from(["same"] * 4 + ["shuffled", "fewer"]))
    if how == "shuffled":
        c.base = draw(st.permutations(c.base))
    elif how == "fewer":
        c.base = sorted(
            draw(st.lists(st.sampled_from(c.base), min_size=1, max_size=len(hips) - 1, unique=True))
        )
    only = [
        f"{draw(st.sampled_from(['Hips/', 'Prop/', '']))}{draw(names)}_a{k}"
        for k in range(draw(st.integers(0, 2)))
    ]
    odd = draw(st.sampled_from([None] * 30 + ["twice"] + BAD_TOKENS))
    if odd is not None:
        only.append(hips[c.base[0]] if odd == "twice" else odd)
    c.anim_extra = draw(st.permutations(animated + [t for t in only if t not in taken or odd == "twice"]))
    c.anim_order = draw(st.permutations([False] * len(c.base) + [True] * len(c.anim_extra)))
    c.modes = {
        "rotations": draw(st.sampled_from(["keep", "keep", "more", "default"])),
        "translations": draw(st.sampled_from(["keep", "keep", "more", "default", "none"])),
        "scales": draw(st.sampled_from(["keep", "more", "none"])),
    }
    quarters = st.lists(st.integers(4004, 4388), min_size=1, max_size=2, unique=True)
    c.new_times = sorted(q / 4 for q in draw(quarters))  # frames 1001-1097, on and off frames
    c.seed = draw(st.integers(0, 2**32 - 1))
    c.model = draw(st.sampled_from(["interp", "spline"]))
    _expect(c, hips, taken, odd)
    return c


def _extra_roots(draw, c: Case, hips: tuple[str, ...], taken: set[str]) -> list[str]:
    """0-2 extra root hierarchies in ``c.roots`` (1-4 joints; sometimes as many as the
    character, a tie, or one more, so that it is the character; sometimes with a joint under
    an unlisted path); their joints the animation lists (all, some or none of each)."""
    animated: list[str] = []
    for r in range(draw(st.integers(0, 2))):
        root = f"{draw(names)}{r}"
        if root in taken:
            root += "_x"
        kind = draw(st.sampled_from(["small"] * 5 + ["tie", "larger", "gap"]))
        size = {"tie": len(hips), "larger": len(hips) + 1}.get(kind, draw(st.integers(1, 4)))
        tree = [root]
        for k in range(size - 1):  # a chain for the big ones (deep paths), a tree otherwise
            up = tree[-1] if kind in ("tie", "larger") else draw(st.sampled_from(tree))
            tree.append(f"{up}/b{k}")
        if kind == "gap":
            tree.append(f"{root}/Gone/c")
        taken.update(tree)
        c.roots.append(tree)
        how = draw(st.sampled_from(["all", "some", "none"]))
        animated += [t for t in tree if how == "all" or (how == "some" and draw(st.booleans()))]
    return animated


def _second(draw, c: Case, hips: tuple[str, ...]) -> list[str]:
    """A second skeleton sharing the animation: its extra roots (chains ``S0``, ``S1``),
    its order of the walk's joints, sometimes another rest pose; the extra joints the
    animation lists."""
    c.second, animated = [], []
    for r in range(draw(st.integers(0, 2))):
        size = draw(st.sampled_from([1, 2, 3, 1, 2, len(hips), len(hips) + 1]))
        c.second.append([f"S{r}"] + [f"S{r}" + "".join(f"/s{k}" for k in range(i)) for i in range(1, size)])
        animated += [t for t in c.second[-1] if draw(st.booleans())]
    n = sum(len(t) for t in c.second)
    c.second_order = draw(st.permutations([False] * len(hips) + [True] * n))
    left = list(range(len(hips)))
    while left:  # any order UsdSkel accepts: a joint once its parent is listed
        ready = [i for i in left if hips[i].rpartition("/")[0] not in [hips[j] for j in left]]
        c.second_hips.append(draw(st.sampled_from(ready)))
        left.remove(c.second_hips[-1])
    if draw(st.integers(0, 3)) == 0:
        c.second_rest = (draw(st.integers(0, len(hips) - 1)), draw(st.sampled_from(["moved", "turned"])))
    return animated


def _expect(c: Case, hips: tuple[str, ...], taken: set[str], odd: str | None) -> None:
    """The oracle: ``c.character`` (the root of the largest hierarchy) and ``c.expect``."""
    sizes = sorted([len(hips)] + [len(t) for t in c.roots], reverse=True)
    if sizes[0] > len(hips):
        c.character = next(t[0] for t in c.roots if len(t) == sizes[0])
    filled = [
        t for t in [hips[i] for i in c.base] + c.anim_extra if t.split("/")[0] == c.character and t in taken
    ]
    second = sorted([len(hips)] + [len(t) for t in c.second or []], reverse=True)
    if c.roots and (any("/Gone/" in t for tree in c.roots for t in tree) or sizes[0] == sizes[1]):
        c.expect = "refused"  # no one hierarchy is the character
    elif odd is not None or not filled:
        c.expect = "refused"  # a broken animation, or one that animates none of the character
    elif c.second is not None and (
        second[0] != len(hips) or second[1:2] == second[:1] or c.character != "Hips" or c.second_rest
    ):
        c.expect = "refused"  # the skeletons' characters are not one rig, or no character
    elif {c.modes["rotations"], c.modes["translations"]} <= {"default", "none"}:
        c.expect = "refused late"  # no keys: refused once the shot is read (fill.plan)


def _interleave(base: list, extra: list, order: list[bool]) -> list:
    a, b = iter(base), iter(extra)
    return [next(b) if take else next(a) for take in order]


def _value(rng, name: str) -> list[float]:
    if name == "rotations":
        q = rng.uniform(-1, 1, 4)
        return list(q / np.linalg.norm(q) if np.linalg.norm(q) > 0.2 else (0.0, 0.0, 0.0, 1.0))
    if name == "translations":
        return list(rng.uniform(-100, 100, 3))
    return list(rng.uniform(0.25, 4, 3))


def _build(shot: Path, c: Case) -> None:
    """Writes the case into the copy ``shot`` of the example walk."""
    from pxr import Gf, Usd, Vt

    rng = np.random.default_rng(c.seed)
    stage = Usd.Stage.Open(str(shot))
    skel = stage.GetPrimAtPath(SKEL)
    extra_skel = [t for tree in c.roots for t in tree]
    joints = skel.GetAttribute("joints")
    joints.Set(Vt.TokenArray(_interleave(list(joints.Get()), extra_skel, c.skel_order)))
    for n in ("restTransforms", "bindTransforms"):
        a = skel.GetAttribute(n)
        mats = [Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(*rng.uniform(-5, 5, 3))) for _ in extra_skel]
        a.Set(Vt.Matrix4dArray(_interleave(list(a.Get()), mats, c.skel_order)))
    anim = stage.GetPrimAtPath(ANIM)
    listed = [str(t) for t in anim.GetAttribute("joints").Get()]
    base = [listed[i] for i in c.base]
    anim.GetAttribute("joints").Set(Vt.TokenArray(_interleave(base, c.anim_extra, c.anim_order)))
    for name in ATTRS:
        attr = anim.GetAttribute(name)
        mode = c.modes[name]
        if mode == "none":
            anim.RemoveProperty(name)
            continue
        times = list(attr.GetTimeSamples())
        old = {t: attr.Get(t) for t in times} if times else {None: attr.Get()}
        if mode == "more":  # new samples: the character's value there as USD gives it
            old.update({t: attr.Get(t) for t in c.new_times if t not in old})
            old.pop(None, None)
        if mode == "default":  # one value, no samples: the first
            old = {None: next(iter(old.values()))}
        attr.Clear()
        for t, v in old.items():
            dtype = np.array(v).dtype
            rows = [np.array(_value(rng, name), dtype) for _ in c.anim_extra]
            a = np.array(_interleave(list(np.array(v)[c.base]), rows, c.anim_order), dtype)
            new = type(v).FromNumpy(a)
            attr.Set(new) if t is None else attr.Set(new, t)
    stage.Save()
    if c.second is not None:
        _second_skeleton(shot, c)


def _second_skeleton(shot: Path, c: Case) -> None:
    """A copy of the walker's skeleton (its joints in the order ``c.second_hips``, its rest
    pose as the example's but for ``c.second_rest``, no mesh) with the extra hierarchies
    ``c.second`` (interleaved by ``c.second_order``), bound to the walker's animation."""
    from pxr import Gf, Sdf, Usd, UsdSkel, Vt

    orig = Sdf.Layer.FindOrOpen(str(SHOT))
    layer = Sdf.Layer.FindOrOpen(str(shot))
    assert Sdf.CopySpec(layer, "/World/Walker", layer, "/World/Walker2")
    walker2 = layer.GetPrimAtPath("/World/Walker2")
    for name in [n for n in walker2.nameChildren.keys() if n != "Skel"]:
        del walker2.nameChildren[name]
    del layer.GetPrimAtPath("/World/Walker2/Skel").nameChildren["Anim"]
    stage = Usd.Stage.Open(layer)
    prim = stage.GetPrimAtPath("/World/Walker2/Skel")
    UsdSkel.BindingAPI(prim).GetAnimationSourceRel().SetTargets([ANIM])
    extra = [t for tree in c.second for t in tree]
    hips = list(orig.GetAttributeAtPath(f"{SKEL}.joints").default)
    order = c.second_order
    joints = _interleave([hips[i] for i in c.second_hips], extra, order)
    prim.GetAttribute("joints").Set(Vt.TokenArray(joints))
    for n in ("restTransforms", "bindTransforms"):
        mats = [Gf.Matrix4d(m) for m in orig.GetAttributeAtPath(f"{SKEL}.{n}").default]
        if c.second_rest and n == "restTransforms":  # another rig: 1 cm, or 10 degrees
            m = mats[c.second_rest[0]]
            if c.second_rest[1] == "moved":
                m.SetTranslateOnly(m.ExtractTranslation() + Gf.Vec3d(1, 0, 0))
            else:
                m.SetRotateOnly(m.ExtractRotation() * Gf.Rotation(Gf.Vec3d(0, 0, 1), 10))
        mats = [mats[i] for i in c.second_hips]
        prim.GetAttribute(n).Set(Vt.Matrix4dArray(_interleave(mats, [Gf.Matrix4d(1)] * len(extra), order)))
    layer.Save()


def _plain(monkeypatch, capsys, folder: Path, model: str):
    """The ``model`` fill of the unchanged walk: (the joints it lists, its samples)."""
    shot = folder / model / "sh010.usda"
    shot.parent.mkdir()
    shot.write_bytes(SHOT.read_bytes())
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", model)
    assert rc == 0, err
    return layer_samples(shot.parent / "sh010.tween.v001.usda", FILLED, ATTRS)


def _refused(rc: int, err: str, shot: Path, before: str, c: Case) -> None:
    lines = err.strip().splitlines()
    # The reader's warnings (several roots, joints the skeleton lacks) wait with fill.plan's
    # own notes until every check has passed: a refusal, early or late, is its one line.
    assert rc == 2 and len(lines) == 1, (c, err)
    assert lines[0].startswith(f"tween: error: {shot} /World/Walker"), (c, err)  # file and prim
    assert digest(shot) == before and sorted(p.name for p in shot.parent.iterdir()) == [shot.name], c


def _at_rest(stage, c: Case, name: str, joints: list[str], kept: list[int], got: dict) -> None:
    """An attribute the animation never authors: the joints not filled show the filled
    skeleton's rest there (UsdSkel poses nothing from such an animation), or the identity
    for joints no skeleton has, at every time written."""
    from pxr import Gf

    skel = stage.GetPrimAtPath(SKEL)
    rest = dict(
        zip(skel.GetAttribute("joints").Get(), skel.GetAttribute("restTransforms").Get(), strict=True)
    )
    for i in kept:
        m = rest.get(joints[i])
        want = np.array(UNAUTHORED[name], np.float64)
        if m is not None and name == "translations":
            want = np.array(m.ExtractTranslation(), np.float32)
        elif m is not None and name == "rotations":
            q = Gf.Matrix4d(m).ExtractRotationQuat()
            want = np.array([*q.GetImaginary(), q.GetReal()])
        for t, v in got.items():
            if name == "rotations":  # q and -q are one rotation
                assert abs(abs(np.dot(v[i], want)) - 1) < 1e-6, (c, name, t, joints[i])
            else:
                assert np.allclose(v[i], want, rtol=0, atol=1e-3 if name == "scales" else 0), (c, name, t)


def _filled(shot: Path, c: Case, plain) -> None:
    from pxr import Usd

    stage = Usd.Stage.Open(str(shot))  # held: its prims expire with it
    src = stage.GetPrimAtPath(ANIM)
    authored = [str(t) for t in src.GetAttribute("joints").Get()]
    joints, got = layer_samples(shot.parent / "sh010.tween.v001.usda", FILLED, ATTRS)
    assert joints == authored, c
    skel = set(str(t) for t in stage.GetPrimAtPath(SKEL).GetAttribute("joints").Get())
    char = [i for i, t in enumerate(joints) if t in skel and t.split("/")[0] == c.character]
    kept = [i for i in range(len(joints)) if i not in char]
    # The keys are the rotations' and translations' sample times (read.Character.sample_times).
    keys = sorted(
        set().union(*(src.GetAttribute(n).GetTimeSamples() for n in ATTRS[:2] if src.GetAttribute(n)))
    )
    for name in ATTRS:
        attr = src.GetAttribute(name)
        assert set(keys) <= set(got[name]), (c, name)
        if not (attr and attr.HasAuthoredValue()):
            _at_rest(stage, c, name, joints, kept, got[name])
            continue
        for t, v in got[name].items():
            want = np.array(attr.Get(t))
            # The joints not filled: what the animator's animation gives at that time.
            assert np.array_equal(v[kept], want[kept]), (c, name, t)
            if t in keys and (t in attr.GetTimeSamples() or not attr.GetNumTimeSamples()):
                # Keys bit for bit, every joint (a key of the other attribute alone keys
                # the channels it samples: the model fills this one there; an attribute
                # of one value is keyed at every key).
                assert np.array_equal(v, want), (c, name, t)
    pj, pv = plain[c.model]
    same = c.base == list(range(len(pj))) and c.modes == dict.fromkeys(ATTRS, "keep")
    if c.character == "Hips" and same:
        assert [joints[i] for i in char] == pj, c
        for name in ATTRS:  # the character: bit for bit the fill of the walk without the extras
            assert sorted(got[name]) == sorted(pv[name]), (c, name)
            for t, v in got[name].items():
                assert np.array_equal(v[char], pv[name][t]), (c, name, t)


def _hips() -> tuple[str, ...]:
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(SHOT))
    return tuple(layer.GetAttributeAtPath(f"{SKEL}.joints").default)


def test_generated_extra_joints_and_roots_fill_or_refuse_in_one_line(tmp_path, monkeypatch, capsys):
    plain = {m: _plain(monkeypatch, capsys, tmp_path, m) for m in ("interp", "spline")}

    @settings(max_examples=FILL_EXAMPLES, deadline=None, database=None,
              suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])  # fmt: skip
    @given(cases(_hips()))
    def check(c: Case):
        with tempfile.TemporaryDirectory() as d:
            shot = Path(d) / "sh010.usda"
            shot.write_bytes(SHOT.read_bytes())
            _build(shot, c)
            before = digest(shot)
            rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", c.model)
            assert "Traceback" not in err, (c, err)
            if c.expect != "fill":
                _refused(rc, err, shot, before, c)
                return
            assert rc == 0 and "tween: error:" not in err, (c, err)
            assert digest(shot) == before, c
            _filled(shot, c, plain)

    check()
