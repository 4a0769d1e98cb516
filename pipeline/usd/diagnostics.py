"""USD's own diagnostics while a shot is read: kept off stderr, folded into our one-line error.

USD reports problems it can work around (``Warning: ... Joint 0 has mis-ordered parent
20``, ``Ill-formed SdfPath <...>``) by printing them on stderr and carrying on; the
failure they explain comes later, as our error. While :func:`usd_diagnostics` is active a
``UsdUtils.CoalescingDiagnosticDelegate`` receives every warning, status and error that
TfDiagnosticMgr would print (from any thread): they are collected, not printed. When a
:class:`~pipeline.errors.ShotError` leaves the block, the captured message that concerns
it (one naming its prim, else the first warning) is appended to its line; a
``Tf.ErrorException`` leaving the block becomes a ShotError naming the shot.
"""

from __future__ import annotations

import re
from contextlib import contextmanager
from dataclasses import dataclass, field

from pipeline.errors import ShotError

#: The longest USD message folded into an error line (characters).
MAX_FOLDED = 300


@dataclass(frozen=True)
class Diagnostic:
    kind: str  # "warning", "error" or "status"
    text: str  # the commentary on one line ("/World/Skel -- invalid topology: ...")


def _one_line(text: str) -> str:
    """USD's text on one line, without the C++ addresses it names objects by (``<0x5f…>``)."""
    return " ".join(re.sub(r"\s*<0x[0-9a-fA-F]+>", "", str(text)).split())


def _kind(item) -> str:
    code = str(getattr(item, "diagnosticCodeString", "") or getattr(item, "diagnosticCode", ""))
    if "WARNING" in code:
        return "warning"
    if "STATUS" in code:
        return "status"
    return "error"


def short(text: str) -> str:
    """A USD message as a clause of our line: one line, its first sentence, the leading
    ``<prim path> -- `` dropped (our line names the prim itself), at most MAX_FOLDED chars."""
    t = _one_line(text)
    t = re.sub(r"^/\S* -- ", "", t)
    first = re.split(r"(?<=[a-z0-9)\]>'])\. (?=[A-Z])", t, maxsplit=1)[0].rstrip(".")
    if len(first) > MAX_FOLDED:
        first = first[: MAX_FOLDED - 1].rstrip() + "…"
    return first


_ERROR = re.compile(r"Error in '[^']*' at line \d+ in file \S+ : '(.*?)'\s*(?=\n\s*Error in |\Z)", re.S)


def error_text(exc, path: str | None = None) -> str:
    """The telling part of a ``Tf.ErrorException``: of the errors it carries, the first
    that is not the closing "Failed to open layer", preferring one that gives a line in
    ``path`` (``line 5:5: invalid value for field ...``), as one short clause."""
    try:
        raw = str(exc).strip()
    except UnicodeDecodeError:  # usd-core's message quotes bytes of the file that are not UTF-8
        return "it holds bytes that are not UTF-8 text"
    found = [_one_line(m) for m in _ERROR.findall(raw)] or [
        _one_line(ln) for ln in raw.splitlines() if ln.strip()
    ]
    if not found:
        return "unreadable"
    telling = [t for t in found if not t.startswith("Failed to open layer")] or found
    if path:
        where = [t for t in telling if t.startswith(f"{path}:")]
        if where:
            return short("line " + where[0][len(path) + 1 :])
    return short(telling[0])


def _commentary(item) -> str:
    """The item's text. USD cuts a name it quotes at a byte, which may fall inside a
    character (``Ill-formed SdfPath <Head😀>: ... at character 5``); the binding then cannot
    decode the text at all, and it is dropped ("": the check that refuses the name says why)."""
    try:
        return item.commentary
    except UnicodeDecodeError:
        return ""


@dataclass
class Diagnostics:
    """What USD posted while the block ran, in order (duplicates dropped)."""

    items: list[Diagnostic] = field(default_factory=list)

    def _take(self, delegate) -> None:
        for item in delegate.TakeUncoalescedDiagnostics():
            d = Diagnostic(_kind(item), _one_line(_commentary(item)))
            if d.text and d not in self.items:
                self.items.append(d)

    def __bool__(self) -> bool:
        return bool(self.items)

    def __len__(self) -> int:
        return len(self.items)

    def texts(self) -> list[str]:
        return [d.text for d in self.items]

    def relevant(self, *hints: str | None) -> str | None:
        """The message that concerns a failure: the first naming one of ``hints`` (prim
        paths, joint tokens), else the first error, else the first warning; None when USD
        said nothing (status lines never count)."""
        pool = [d for d in self.items if d.kind != "status"]
        for h in (h for h in hints if h):
            for d in pool:
                if h in d.text:
                    return d.text
        for kind in ("error", "warning"):
            for d in pool:
                if d.kind == kind:
                    return d.text
        return None

    def fold(self, err: ShotError) -> ShotError:
        """``err`` with the relevant USD message appended (``...; USD: <message>``), or
        ``err`` itself when there is none or its line already carries it."""
        text = self.relevant(err.prim)
        if not text:
            return err
        clause = short(text)
        msg = str(err)
        # Already said (our own check may quote USD: "invalid topology: Joint 0 ..." vs "Joint 0 ...").
        tails = [clause] + [clause.split(": ", i)[-1] for i in range(1, clause.count(": ") + 1)]
        if not clause or any(len(t) > 10 and t in msg for t in tails):
            return err
        where = f"{err.shot} {err.prim}" if err.prim else err.shot
        base = msg[len(where) + 2 :] if msg.startswith(where + ": ") else msg
        return ShotError(err.shot, f"{base}; USD: {clause}", err.prim)


@contextmanager
def usd_diagnostics(shot: str | None = None, fold: bool = True):
    """Collects USD's diagnostics while the block runs (none reach stderr) into the
    yielded :class:`Diagnostics`. ``fold``: a ShotError leaving the block gets the relevant
    one appended. With ``shot``, a ``Tf.ErrorException`` leaving it becomes a ShotError."""
    from pxr import Tf, UsdUtils

    diags = Diagnostics()
    delegate = UsdUtils.CoalescingDiagnosticDelegate()
    try:
        yield diags
    except ShotError as e:
        diags._take(delegate)
        if not fold:
            raise
        folded = diags.fold(e)
        if folded is e:
            raise
        raise folded from None
    except Tf.ErrorException as e:
        diags._take(delegate)
        if shot is None:
            raise
        raise ShotError(shot, f"USD error: {error_text(e, shot)}") from None
    finally:
        diags._take(delegate)
        # Unregisters it from TfDiagnosticMgr (its destructor): later diagnostics print again.
        del delegate
