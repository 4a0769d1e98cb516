"""Model ÷ interpolation ratios, as the model card and the research scripts print them.

``evaluate`` (pipeline.bench.run) returns ``{transition: {metric: value}}``; a ``tween bench``
JSON file holds the same under ``results[method]`` with the transitions as strings. These
helpers divide one method's rows by a baseline's (interpolation) and format them as the
card's cells: ``"0.812 / 0.640 / 0.571 / 0.553"`` over the transitions.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from pipeline.data.protocol import TRANSITIONS

#: The metrics of the card's ratio rows, in its column order.
CARD_METRICS = ("L2P", "L2Q", "NPSS", "skate")
#: Rows of a bench file that are baselines, not models.
BASELINES = ("interp", "zero")


def ratios(rows: Mapping, base: Mapping, metric: str) -> dict:
    """``{transition: rows[t][metric] / base[t][metric]}`` over the transitions of ``rows``."""
    return {t: rows[t][metric] / base[t][metric] for t in rows}


def cell(values: Iterable[float], digits: int = 3) -> str:
    """Values joined the card's way: ``"0.812 / 0.640 / ..."``."""
    return " / ".join(f"{v:.{digits}f}" for v in values)


def ratio_cell(rows: Mapping, base: Mapping, metric: str, digits: int = 3) -> str:
    """One card cell: ``metric`` of ``rows`` ÷ ``base`` at each transition."""
    return cell(ratios(rows, base, metric).values(), digits)


def model_row(results: Mapping) -> str:
    """The one model row of a ``tween bench`` file's ``results`` (not interp, not zero)."""
    models = [k for k in results if k not in BASELINES]
    if not models:
        raise ValueError(f"no model row among {', '.join(results) or 'no rows'}")
    return models[0]


def bench_ratio_row(
    label: str,
    results: Mapping,
    metrics: Iterable[str] = CARD_METRICS,
    transitions: Iterable = TRANSITIONS,
) -> str:
    """A Markdown table row ``| label | L2P ratios | L2Q ratios | NPSS ratios | skate ratios |``
    of the model in a ``tween bench`` file's ``results`` against its ``interp`` row."""
    if "interp" not in results:
        raise ValueError("no interp row to divide by")
    model = model_row(results)
    keys = [str(t) for t in transitions]
    rows = {t: results[model][t] for t in keys}
    base = {t: results["interp"][t] for t in keys}
    return f"| {label} | " + " | ".join(ratio_cell(rows, base, m) for m in metrics) + " |"
