"""A Ctrl-C landing just after a command made a folder, for the tests of what it leaves."""

from __future__ import annotations

from pathlib import Path


def interrupt_after_mkdir(monkeypatch) -> None:
    """Every ``Path.mkdir`` makes its folder, then raises KeyboardInterrupt: an interrupt
    landing just after the mkdir, before the next line."""
    real = Path.mkdir

    def made_then_interrupted(self, *args, **kwargs):
        real(self, *args, **kwargs)
        raise KeyboardInterrupt

    monkeypatch.setattr(Path, "mkdir", made_then_interrupted)
