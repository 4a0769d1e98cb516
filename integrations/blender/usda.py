"""The two USD text files the extension touches, read and edited as text (Blender's Python
has no ``pxr``): Blender's export of the blocking, and the fill layer's takes. No ``bpy``.

Both are written by USD's own text writer (Sdf), which puts every time sample on its own line
and closes every block at the indentation that opened it; these functions rely on that and
refuse (ValueError, one line) what does not look so.

The blocking: Blender's USD exporter samples every frame of the scene range. The fill reads a
shot's keys from its animation's samples, so :func:`keep_keys` keeps the rotation samples
only on the animator's keyed frames, the translations only where a location is keyed (a key
where only rotations are keyed leaves the root's position free), and writes
``tween:keyedJoints`` where only some bones are keyed (a partial key).
"""

from __future__ import annotations

import re

_ANIM = re.compile(r'^(?P<indent>\s*)def SkelAnimation "(?P<name>[^"]+)"')
_SAMPLES = re.compile(
    r"^(?P<indent>\s*)(?:custom\s+)?(?P<type>\S+)\s+(?P<attr>[\w:]+)\.timeSamples\s*=\s*\{\s*$"
)
_JOINTS = re.compile(r"^\s*uniform token\[\] joints\s*=\s*\[(?P<v>.*)\]\s*$")
_TOKEN = re.compile(r'"([^"]*)"')
EPS = 1e-4  # time codes this close are one frame (as the fill reads them)


_BRACKETS = str.maketrans("", "", "()[] \t")


def _time(line: str) -> float | None:
    """The time code a sample line starts with, or None for any other line."""
    t, sep, _ = line.partition(":")
    if not sep:
        return None
    try:
        return float(t)
    except ValueError:
        return None


def _end(lines: list[str], i: int, indent: str) -> int:
    """The index of the line closing the block opened at or after line ``i``."""
    for j in range(i + 1, len(lines)):
        if lines[j].rstrip() == indent + "}":
            return j
    raise ValueError(f"unclosed block at line {i + 1}")


def _prim_block(lines: list[str], name: str | None = None, suffix: str = "") -> tuple[int, int, str, str]:
    """(first line, closing line, indent, name) of the one SkelAnimation ``def`` (by name)."""
    found = []
    for i, ln in enumerate(lines):
        m = _ANIM.match(ln)
        if m and (name is None or m.group("name") == name) and m.group("name").endswith(suffix):
            found.append((i, m.group("indent"), m.group("name")))
    if len(found) != 1:
        what = f"SkelAnimation {name!r}" if name else "SkelAnimation" + (f" *{suffix}" if suffix else "")
        raise ValueError(f"expected one {what} in the file, found {len(found)}")
    i, indent, nm = found[0]
    return i, _end(lines, i, indent), indent, nm


def _within(t: float, times) -> bool:
    return any(abs(t - k) < EPS for k in times)


def animation_joints(text: str, name: str | None = None) -> list[str]:
    """The joint tokens of the file's SkelAnimation."""
    lines = text.splitlines()
    a, b, _, _ = _prim_block(lines, name)
    for ln in lines[a:b]:
        m = _JOINTS.match(ln)
        if m:
            return _TOKEN.findall(m.group("v"))
    raise ValueError("the SkelAnimation lists no joints")


def keep_keys(text: str, keys, located=None, keyed_joints: dict | None = None) -> str:
    """Blender's export with samples only on the keys.

    ``keys``: the keyed frames (rotations and scales keep these samples); ``located``: the
    frames where a location is keyed (translations keep these; default ``keys``; the first
    and last key always); ``keyed_joints``: {frame: joint tokens keyed there} for the partial
    keys (a key absent from it keys every joint).
    """
    keys = sorted({float(k) for k in keys})
    if len(keys) < 2:
        raise ValueError(f"{len(keys)} keyed frame(s): the fill needs at least two keys")
    located = sorted({float(k) for k in (keys if located is None else located)} | {keys[0], keys[-1]})
    lines = text.splitlines()
    a, b, indent, _ = _prim_block(lines)
    joints = set(animation_joints(text))
    keep = {"rotations": keys, "scales": keys, "translations": located}
    out, i, seen = lines[: a + 1], a + 1, set()
    while i < b:
        ln = lines[i]
        m = _SAMPLES.match(ln)
        if not m or m.group("attr") not in keep:
            out.append(ln)
            i += 1
            continue
        j = _end(lines, i, m.group("indent"))
        kept = []
        for k in range(i + 1, j):
            t = _time(lines[k])
            if t is None:
                raise ValueError(f"line {k + 1}: not a time sample")
            if _within(t, keep[m.group("attr")]):
                kept.append(lines[k])
        seen.add(m.group("attr"))
        out += [ln, *kept, lines[j]]
        i = j + 1
    if "rotations" not in seen:
        raise ValueError("the armature's animation has no rotation samples (is the action keyed?)")
    partial = {float(t): list(v) for t, v in (keyed_joints or {}).items() if _within(float(t), keys)}
    bad = sorted({j for v in partial.values() for j in v} - joints)
    if bad:
        raise ValueError(f"keyed joint {bad[0]!r} is not a joint of the animation")
    if partial:
        pad = indent + "    "
        block = [f"{pad}custom token[] tween:keyedJoints.timeSamples = {{"]
        for t in sorted(partial):
            toks = ", ".join(f'"{j}"' for j in partial[t])
            block.append(f"{pad}    {t:g}: [{toks}],")
        block.append(f"{pad}}}")
        at = next(k for k in range(a + 1, len(out)) if out[k].strip() == "{") + 1
        out[at:at] = block
    out += lines[b:]
    return "\n".join(out) + "\n"


def _samples(lines: list[str], a: int, b: int) -> dict[str, dict[float, list[tuple[float, ...]]]]:
    """{attribute: {time: [tuple, …]}} of every numeric ``.timeSamples`` between lines a and b
    (``tween:keyedJoints``' tokens are not read)."""
    out: dict[str, dict[float, list[tuple[float, ...]]]] = {}
    i = a
    while i < b:
        m = _SAMPLES.match(lines[i])
        if not m:
            i += 1
            continue
        j = _end(lines, i, m.group("indent"))
        if m.group("type").startswith(("token", "string")):
            i = j + 1
            continue
        vals: dict[float, list[tuple[float, ...]]] = {}
        for s in lines[i + 1 : j]:
            t = _time(s)
            if t is None:
                continue
            v = s.partition(":")[2]
            # one split of the whole line, not a regex per tuple: long shots have millions of numbers
            n = v[v.find("(") + 1 : v.find(")")].count(",") + 1
            nums = [float(x) for x in v.translate(_BRACKETS).split(",") if x]
            vals[t] = [tuple(nums[k : k + n]) for k in range(0, len(nums), n)]
        out[m.group("attr")] = vals
        i = j + 1
    return out


def read_samples(text: str, name: str | None = None) -> tuple[list[str], dict]:
    """(joint tokens, {attribute: {time: [tuple, …]}}) of the file's SkelAnimation ``def``."""
    lines = text.splitlines()
    a, b, _, nm = _prim_block(lines, name)
    return animation_joints(text, nm), _samples(lines, a, b)


class Takes:
    """A fill layer's takes, found at once and read one at a time (:meth:`samples`): a long
    shot's takes are millions of numbers, read between two ticks of Blender's timer each.

    ``anim``: the filled animation's name (``<anim>_tween``; default: the layer's only one).
    A fill of one take has no variant set: its samples are take 0."""

    def __init__(self, text: str, anim: str | None = None):
        self.lines = lines = text.splitlines()
        a, b, _, self.name = _prim_block(lines, f"{anim}_tween" if anim else None, "_tween")
        self.joints = animation_joints(text, self.name)
        self.spans: dict[int, tuple[int, int]] = {}
        vs = next(
            (i for i, ln in enumerate(lines) if re.match(r'^\s*variantSet "tweenTake" = \{\s*$', ln)), None
        )
        if vs is None:
            self.spans[0] = (a, b)
        else:
            end = _end(lines, vs, re.match(r"^(\s*)", lines[vs]).group(1))
            i = vs + 1
            while i < end:
                m = re.match(r'^(?P<indent>\s*)"take(?P<n>\d+)" \{\s*$', lines[i])
                if not m:
                    i += 1
                    continue
                j = _end(lines, i, m.group("indent"))
                # the over of this animation inside the variant
                over = next(
                    (k for k in range(i, j) if re.match(rf'^\s*over "{re.escape(self.name)}"\s*$', lines[k])),
                    None,
                )
                if over is not None:
                    self.spans[int(m.group("n"))] = (
                        over,
                        _end(lines, over, re.match(r"^(\s*)", lines[over]).group(1)),
                    )
                i = j + 1
        if not self.spans:
            raise ValueError(f"the fill layer holds no take of {self.name}")

    def samples(self, take: int) -> dict:
        """{"rotations"|"translations"|"scales": {time: [(w, x, y, z) | (x, y, z), …]}}."""
        s = _samples(self.lines, *self.spans[take])
        if not s.get("rotations"):
            raise ValueError(f"take {take} of {self.name} has no rotation samples")
        return s


def read_takes(text: str, anim: str | None = None) -> tuple[list[str], dict[int, dict]]:
    """A fill layer's takes, all read: (joint tokens, {take: :meth:`Takes.samples`})."""
    t = Takes(text, anim)
    return t.joints, {n: t.samples(n) for n in sorted(t.spans)}


_LAYER_NAME = re.compile(r"^(?P<shot>.+)\.tween\.v(?P<version>\d+)\.usda$")


def latest_layer(names, shot: str) -> tuple[int, str] | None:
    """(version, file name) of the newest ``<shot>.tween.vNNN.usda`` among ``names``."""
    found = [
        (int(m.group("version")), n) for n in names if (m := _LAYER_NAME.match(n)) and m.group("shot") == shot
    ]
    return max(found) if found else None


def layer_result(text: str) -> dict:
    """The fill's JSON as far as its layer tells it (for a fill whose job Blender no longer
    follows): layer data ``version``, ``takes``, ``review``, ``model``, and each filled
    animation's trust decision (``tween:trust``, ``tween:trustWeight``)."""

    def meta(kind: str, key: str):
        m = re.search(rf'^\s*{kind} {key} = (?:"(?P<s>[^"]*)"|(?P<v>[-0-9.eE]+))\s*$', text, re.M)
        return None if m is None else m.group("s") if m.group("s") is not None else m.group("v")

    out = {"version": int(meta("int", "version") or 0), "takes": int(meta("int", "takes") or 1),
           "review": meta("string", "review"), "model": meta("string", "model") or "", "trust": {}}  # fmt: skip
    lines = text.splitlines()
    for i, ln in enumerate(lines):
        m = _ANIM.match(ln)
        if not m or not m.group("name").endswith("_tween"):
            continue
        block = "\n".join(lines[i : _end(lines, i, m.group("indent"))])
        choice = re.search(r'token tween:trust = "(\w+)"', block)
        weight = re.search(r"double tween:trustWeight = ([-0-9.eE]+)", block)
        out["trust"][m.group("name")] = {
            "choice": choice.group(1) if choice else "",
            "weight": float(weight.group(1)) if weight else None,
        }
    return out
