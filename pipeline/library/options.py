"""The options of a library build, each declared once: ``tween library build`` (in this
process) and ``tween submit-library`` (the farm) offer the same ones
(:func:`with_library_options`), and the farm task turns a job's options back into the
``tween library build`` command line from the same fields (:func:`command_args`)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

from pipeline.errors import TweenError
from pipeline.options import MAX_TEXT, flags_of, job_args, names_a_glob, one_line, option, with_options

#: Seconds a build waits for another build of the library to release its lock
#: (pipeline.library.build.LOCK) before it gives up, exit 2 naming the lock and its holder:
#: one that hung (a stopped process, a dead mount) held every later build for ever.
#: ``tween library build --lock-wait SECONDS`` sets it, from 0 to MAX_LOCK_WAIT_S.
LOCK_WAIT_S = 300.0
MAX_LOCK_WAIT_S = 24 * 3600.0


def check_lock_wait(seconds: float) -> float:
    """``seconds`` when it is a wait ``--lock-wait`` takes; TweenError naming the option."""
    if not 0 <= seconds <= MAX_LOCK_WAIT_S:  # NaN too
        raise TweenError(f"--lock-wait {seconds:g}: must be from 0 to {MAX_LOCK_WAIT_S:g} seconds")
    return seconds


@dataclass
class LibraryBuildOptions:
    """How takes go into a library (JSON-serialisable: it travels to the farm)."""

    add: bool = option(False, "--add", help="Append the takes the library does not hold yet.")
    include: str | None = option(
        None, "--include", help="Only takes whose file name matches these globs (a,b)."
    )
    licence: str | None = option(
        None, "--licence", help="The takes' licence as the studio states it (recorded)."
    )
    name: str | None = option(None, "--name", help="The library's name (default: the folder's).")
    mirror: bool = option(False, "--mirror", help="Also add each take's left/right mirror image.")

    def check(self) -> LibraryBuildOptions:
        """Raises TweenError (one line naming the option) unless the recorded texts are one
        printable line (they go into library.json, every fill's record and ``library info``)
        and ``--include`` names a glob (an empty one read every take)."""
        for flag, v in (("--licence", self.licence), ("--name", self.name)):
            if v is not None and not one_line(v):
                raise TweenError(
                    f"{flag} {v[:60]!r}: must be one line of printable text, at most {MAX_TEXT} characters"
                )
        if self.include is not None and not names_a_glob(self.include):
            raise TweenError(f"--include {self.include!r}: names no file-name glob (e.g. '001_*,002_*'); "
                             "leave it out for every take")  # fmt: skip
        return self

    def as_job(self) -> dict:
        """The options a farm job carries (the ones set)."""
        return {k: v for k, v in asdict(self).items() if v not in (None, False, "")}


#: option name → its ``tween library build`` flag.
FLAGS: dict[str, str] = flags_of(LibraryBuildOptions)


def command_args(options: dict) -> list[str]:
    """The ``tween library build`` flags of a job's options (unknown names are a ValueError)."""
    return job_args(options, FLAGS, "library build")


#: The typer command with every LibraryBuildOptions field as an option (``opts``).
with_library_options = with_options(LibraryBuildOptions, lead=2)
