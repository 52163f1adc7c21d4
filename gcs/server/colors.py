"""One colour per source, for the 3-D view and the page's plots alike (the page loads them from
`/colors.js`, so the two never drift apart)."""

from __future__ import annotations

import json

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


def colors_script() -> str:
    """`window.GCS_COLORS = {source: "#rrggbb", ...}` for the page."""
    hexes = {name: "#{:02x}{:02x}{:02x}".format(*rgb) for name, rgb in COLORS.items()}
    return f"window.GCS_COLORS = {json.dumps(hexes)};\n"
