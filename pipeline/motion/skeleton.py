"""A joint hierarchy with rest offsets, an up axis and a linear unit."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: The linear units a character is measured in (metres per unit): a micrometre to 1,000 km.
#: Beyond them lengths in metres overflow or vanish in float32.
METERS_PER_UNIT = (1e-6, 1e6)
#: The largest length (a rest offset, a translation, a root position) in a rig's own units:
#: 10 km in millimetres. Beyond it nothing is a character, and what is computed from it
#: (FK, the mesh, a rig's size) overflows to NaN.
MAX_LENGTH = 1e7


def topology_problem(names, parents) -> str | None:
    """Why ``parents`` is not one hierarchy under one root, each joint after its parent
    (None: it is): what :class:`Skeleton` refuses, said so that a reader can name its file
    (UsdSkel allows several roots: a joint path whose parent is not listed)."""
    parents = [int(p) for p in parents]
    J = len(parents)
    for j, p in enumerate(parents):
        if not -1 <= p < J:
            return f"joint {names[j]!r} has parent index {p}, not a joint of the {J}"
    roots = [names[j] for j, p in enumerate(parents) if p < 0]
    if len(roots) > 1:
        listed = ", ".join(repr(r) for r in roots[:3]) + (", ..." if len(roots) > 3 else "")
        return f"{len(roots)} root joints ({listed}); a rig is one hierarchy under one root joint"
    for j, p in enumerate(parents):
        if p >= j or (p < 0 and j != 0):
            return f"joint {names[j]!r} comes before its parent (a parent is listed before its children)"
    return None


@dataclass(frozen=True, eq=False)
class Skeleton:
    """Joints in parent-before-child order.

    ``offsets`` are each joint's rest translation in its parent's frame (the root's is its
    rest position). ``meters_per_unit`` follows USD: 0.01 for centimetres.
    """

    names: tuple[str, ...]
    parents: np.ndarray  # (J,) int, -1 for the root
    offsets: np.ndarray  # (J, 3) float32
    up_axis: str = "Y"
    meters_per_unit: float = 0.01
    end_sites: dict[int, np.ndarray] = field(default_factory=dict)  # joint -> end offset (BVH)

    def __post_init__(self):
        parents = np.asarray(self.parents, np.int64)
        offsets = np.asarray(self.offsets, np.float32).reshape(-1, 3)
        object.__setattr__(self, "parents", parents)
        object.__setattr__(self, "offsets", offsets)
        object.__setattr__(self, "names", tuple(self.names))
        if len(self.names) != len(parents) or len(parents) != len(offsets):
            raise ValueError("skeleton: names, parents and offsets differ in length")
        why = topology_problem(self.names, parents)
        if why:
            raise ValueError(f"skeleton: {why}")
        if self.up_axis not in ("Y", "Z"):
            raise ValueError(f"skeleton: up axis must be Y or Z, not {self.up_axis!r}")

    def __len__(self) -> int:
        return len(self.names)

    def __eq__(self, other) -> bool:
        return (
            isinstance(other, Skeleton)
            and self.names == other.names
            and np.array_equal(self.parents, other.parents)
            and np.allclose(self.offsets, other.offsets, atol=1e-5)
        )

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no joint named {name!r}") from None

    def children(self, j: int) -> list[int]:
        return [c for c, p in enumerate(self.parents) if p == j]

    def bone_lengths(self) -> np.ndarray:
        return np.linalg.norm(self.offsets, axis=-1)

    def subset(self, names: list[str] | tuple[str, ...]) -> Skeleton:
        """The skeleton restricted to ``names`` (each one's nearest kept ancestor is its parent).

        Offsets of kept joints whose parent was dropped are composed through the dropped
        joints' rest offsets, which is exact only when those joints carry no rotation.
        """
        keep = [self.index(n) for n in names]
        if sorted(keep) != keep:
            raise ValueError("subset: names must keep the skeleton's order")
        pos = {j: i for i, j in enumerate(keep)}
        parents, offsets = [], []
        for j in keep:
            off = self.offsets[j].astype(np.float64).copy()
            p = self.parents[j]
            while p >= 0 and p not in pos:
                off += self.offsets[p]
                p = self.parents[p]
            parents.append(pos[p] if p >= 0 else -1)
            offsets.append(off)
        return Skeleton(
            tuple(names), np.array(parents), np.array(offsets, np.float32), self.up_axis, self.meters_per_unit
        )
