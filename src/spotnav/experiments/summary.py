"""The report's opening: one table of the thesis's headline figures beside spotnav's, with a verdict each, and
where each full table is below.

Each study gives its rows as :class:`~spotnav.experiments.report.Headline` (Table 4.1, the ellipse tests, the
paths at 1 W in both exposures, the deformed and the larger eye); :func:`summary_lines` puts them in one table
that fits the report's first screen. :func:`error_headline` is the row of a path's mean and max tip error.
"""

from __future__ import annotations

from collections.abc import Sequence

from spotnav.experiments.report import Experiment, Headline, markdown_table
from spotnav.experiments.runner import ErrorSummary

__all__ = ["AS_PRINTED", "anchor", "error_headline", "pair_text", "ratio_verdict", "summary_lines"]

AS_PRINTED = 1.5  # a figure within this factor of the printed one (either way) reproduces it
SUMMARY_HEADING = "Summary: the thesis's figures beside spotnav's"


def anchor(heading: str) -> str:
    """The link to a heading as GitHub makes it: lower case, punctuation dropped, spaces to hyphens."""
    kept = "".join(c for c in heading.lower() if c.isalnum() or c in " -_")
    return "#" + kept.replace(" ", "-")


def pair_text(summary: ErrorSummary, digits: int = 3) -> str:
    """Mean / max tip error (mm), with the count of frames ``ok`` where some gave no pose; ``-`` and why for none."""
    if not summary.ok:
        return f"- ({summary.why_none})"
    text = f"{summary.mean_mm:.{digits}f} / {summary.max_mm:.{digits}f}"
    return text if summary.ok == summary.frames else f"{text} ({summary.ok}/{summary.frames} ok; {summary.refusals})"


def ratio_verdict(ours: float, printed: float) -> str:
    """``as printed (1.2 x)``, ``over the printed (3.1 x)`` or ``under the printed (0.4 x)``: within a factor of
    :data:`AS_PRINTED` either way is as printed."""
    ratio = ours / printed
    word = "as printed" if 1 / AS_PRINTED <= ratio <= AS_PRINTED else "over" if ratio > 1 else "under"
    return f"{word} ({ratio:.2g} x)"


def error_headline(
    figure: str, printed: tuple[float, float], plain: ErrorSummary, precise: ErrorSummary, section: str
) -> Headline:
    """A summary row of mean / max tip error: the thesis's printed pair, the thesis's method and the precise method.

    The verdict compares the thesis's method's mean to the printed one (:func:`ratio_verdict`) and says how many
    times smaller the precise method's mean is.
    """
    verdict = f"thesis's method {ratio_verdict(plain.mean_mm, printed[0])}" if plain.ok else "thesis's method: no pose"
    if precise.ok:
        verdict += f"; precise {printed[0] / precise.mean_mm:.0f} x under the printed mean"
    return Headline(
        figure, f"{printed[0]:.3f} / {printed[1]:.3f}", pair_text(plain), pair_text(precise, 4), verdict, section
    )


def summary_lines(experiments: Sequence[Experiment]) -> list[str]:
    """The report's opening section: the table of every experiment's headlines and a line linking every section.

    Each experiment's section is named by its Markdown's first heading.
    """
    headlines = [h for e in experiments for h in e.headlines]
    header = ["figure (thesis's table)", "thesis", "spotnav: thesis's method", "spotnav: precise", "verdict", "full"]
    rows = [
        [h.figure, h.thesis, h.plain, h.precise, h.verdict, f"[{h.section.split(':')[0]}]({anchor(h.section)})"]
        for h in headlines
    ]
    sections = [_first_heading(e.markdown) for e in experiments]
    where = " · ".join(f"[{s.split(':')[0]}]({anchor(s)})" for s in sections if s)
    lines = [f"## {SUMMARY_HEADING}", ""]
    if rows:
        lines += [
            "Tip errors are mean / max over a path's poses in mm at 1 W (the thesis's power); spotnav's are "
            "simulated in the thesis's setup (Table 6.8). The thesis's method is spotnav's implementation of it; "
            "precise is spotnav's method with the exact setup. A verdict's ratio is spotnav's thesis's method "
            f"over the printed mean: as printed within {AS_PRINTED:g} x either way.",
            "",
            *markdown_table(header, rows),
        ]
    else:
        lines.append("This run measured none of the thesis's printed figures (see `--only`).")
    return [*lines, "", f"Full tables below: {where}." if where else "No section below.", ""]


def _first_heading(markdown: str) -> str:
    """The text of the first Markdown heading in ``markdown`` (``""``: none)."""
    for line in markdown.splitlines():
        if line.startswith("#"):
            return line.lstrip("#").strip()
    return ""
