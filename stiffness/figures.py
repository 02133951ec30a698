"""What every figure the toolkit draws shares: its margins fixed in inches, and its PNG bytes.

Foundation layer (imports nothing of the package; matplotlib's types only for type checking).
Figures are drawn at their own size: margins set in inches (:func:`margins`, text has a fixed
size in points) need no tight-bbox pass, which draws a figure twice to measure it.
"""

from __future__ import annotations

import io
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def margins(fig: Figure, left: float, right: float, bottom: float, top: float,
            wspace: float, hspace: float) -> None:
    """Set the subplot margins of ``fig`` in inches (left, right, bottom, top), and the gaps
    between panels as fractions of their mean width (``wspace``) and height (``hspace``)."""
    width, height = fig.get_size_inches()
    fig.subplots_adjust(left=left / width, right=1.0 - right / width, bottom=bottom / height,
                        top=1.0 - top / height, wspace=wspace, hspace=hspace)


def png(fig: Figure, dpi: int) -> bytes:
    """The PNG bytes of ``fig`` at its own size and ``dpi`` (dots per inch)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()
