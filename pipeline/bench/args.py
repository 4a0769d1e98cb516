"""Argument types of the benches' ``python -m`` commands: each refuses a value no bench can
run on (argparse names the option: ``argument --every: ...``)."""

from __future__ import annotations

import argparse
import math


def _int(text: str, lo: int, hi: int, what: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: {what}, a whole number from {lo} to {hi}") from None
    if not lo <= v <= hi:
        raise argparse.ArgumentTypeError(f"{v}: {what}, a whole number from {lo} to {hi}")
    return v


def count(text: str) -> int:
    """A number of takes, clips or frames: 1 or more."""
    return _int(text, 1, 10**9, "a count")


def frames_or_all(text: str) -> int:
    """Frames of each take, 0 for all of them."""
    return _int(text, 0, 10**9, "frames (0: all)")


def stride(text: str) -> int:
    """Every N-th take: 1 or more."""
    return _int(text, 1, 10**6, "a stride")


def _ints(text: str, lo: int, hi: int, what: str, many: str) -> tuple[int, ...]:
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if not parts:
        raise argparse.ArgumentTypeError(f"{text!r}: {many}")
    return tuple(_int(p, lo, hi, what) for p in parts)


def spacings(text: str) -> tuple[int, ...]:
    """Key spacings in frames, comma-separated: each from 2 (one frame between keys) to 10000."""
    return _ints(text, 2, 10_000, "a key spacing", "key spacings, comma-separated frames like 10,30")


def subjects(text: str) -> tuple[int, ...]:
    """CMU subject numbers, comma-separated."""
    return _ints(text, 1, 999, "a subject number", "subject numbers, comma-separated like 5,6,7")


def rate(text: str) -> float:
    """A frame rate in frames a second, 0 for the take's own."""
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (v == 0 or 1 <= v <= 1000):
        raise argparse.ArgumentTypeError(f"{text!r}: a frame rate from 1 to 1000, or 0 (the take's)")
    return v
