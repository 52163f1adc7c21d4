"""One colour per source, for every view of the data: the page's plots and 3-D view (through
gcs.server.colors) and the HTML report (gcs.sessions.report), so they never drift apart."""

from __future__ import annotations

#: RGB per source; anything else is drawn grey.
COLORS: dict[str, tuple[int, int, int]] = {
    "onboard": (30, 30, 30),
    "ahrs2": (255, 127, 14),
    "truth": (148, 103, 189),
    "dcm": (214, 39, 40),
    "kf": (31, 119, 180),
    "ekf": (44, 160, 44),
}
OTHER = (128, 128, 128)


def hex_color(source: str) -> str:
    """`#rrggbb` of a source (grey for one without a colour)."""
    return "#{:02x}{:02x}{:02x}".format(*COLORS.get(source, OTHER))
