"""The page's colours (`/colors.js`), from the one table in gcs.core.colors that the 3-D view and
the report use too."""

from __future__ import annotations

import json

from gcs.core.colors import COLORS, OTHER, hex_color

__all__ = ["COLORS", "OTHER", "colors_script"]


def colors_script() -> str:
    """`window.GCS_COLORS = {source: "#rrggbb", ...}` for the page."""
    return f"window.GCS_COLORS = {json.dumps({name: hex_color(name) for name in COLORS})};\n"
