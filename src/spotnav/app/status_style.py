"""One colour and one marker per status, for every picture that tells the statuses apart.

``errors.png`` and ``track.png`` (``spotnav evaluate --out``) and the status swatch of ``spotnav show`` read their
colours here, so a status looks the same in each. ``ok`` alone is green (Okabe and Ito's bluish green); the other
statuses take the rest of Okabe and Ito's colour-blind-safe palette, then Paul Tol's, then greys. Twelve refusals
are more than any palette keeps apart for every reader, so each also has its own marker: under a simulated
deuteranopia, protanopia or tritanopia ``ok`` stays apart from every other status by colour alone, and the
refusals by colour and marker together (``tests/app/test_status_style.py`` measures both).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from types import MappingProxyType

__all__ = ["STATUS_STYLES", "StatusStyle", "status_counts", "status_style"]


def status_counts(statuses: Counter[str], nothing: str) -> str:
    """``"3 ok, 1 lost"``: how many of each status, the commonest first, or ``nothing``."""
    return ", ".join(f"{n} {s}" for s, n in statuses.most_common()) or nothing


@dataclass(frozen=True)
class StatusStyle:
    """How one status is drawn.

    Attributes
    ----------
    colour : str
        ``#RRGGBB``, sRGB.
    marker : str
        A matplotlib marker (``ok``'s frames are drawn as bars or dots, the others as this marker).
    """

    colour: str
    marker: str

    @property
    def rgb(self) -> tuple[int, int, int]:
        """The colour as 8-bit ``(red, green, blue)``."""
        return int(self.colour[1:3], 16), int(self.colour[3:5], 16), int(self.colour[5:7], 16)


# In the order of spotnav.pose.estimate.STATUSES (the test checks that every status has a style).
STATUS_STYLES = MappingProxyType(
    {
        "ok": StatusStyle("#009E73", "o"),  # bluish green
        "no_spot": StatusStyle("#000000", "o"),  # black
        "ambiguous": StatusStyle("#F0E442", "D"),  # yellow
        "too_few_spots": StatusStyle("#882255", "v"),  # wine
        "clipped": StatusStyle("#D55E00", "s"),  # vermillion
        "occluded": StatusStyle("#56B4E9", "^"),  # sky blue
        "wrong_size": StatusStyle("#BBBBBB", "P"),  # light grey
        "unreliable": StatusStyle("#E69F00", "X"),  # orange
        "blurred": StatusStyle("#0072B2", "h"),  # blue
        "uncalibrated": StatusStyle("#332288", "<"),  # indigo
        "miscalibrated": StatusStyle("#AA4499", ">"),  # purple
        "mismatch": StatusStyle("#CC79A7", "*"),  # reddish purple
        "unreadable": StatusStyle("#444444", "p"),  # dark grey
    }
)


_OTHER = StatusStyle("#999999", ".")  # a status this version does not know (a poses.csv from elsewhere)


def status_style(status: str) -> StatusStyle:
    """The style of one of :data:`spotnav.pose.estimate.STATUSES`; a mid grey dot for any other string (a
    ``poses.csv`` written by another version or tool)."""
    return STATUS_STYLES.get(status, _OTHER)
