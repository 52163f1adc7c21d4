"""Where the dashboard's files are: inside the installed package (the wheel's build hook,
setup.py, copies web/public and uPlot there), or in the source checkout (web/ and its
node_modules, for an editable install). Nothing is ever fetched from a CDN."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

PACKAGED = Path(__file__).resolve().parent / "web"
CHECKOUT = Path(__file__).resolve().parents[2] / "web"


@dataclass(frozen=True)
class WebAssets:
    page: Path  # index.html and its scripts
    uplot: Path  # uPlot.iife.min.js and uPlot.min.css


def web_assets() -> WebAssets:
    """The packaged assets if present, else the checkout's; FileNotFoundError says what to do."""
    for assets in (
        WebAssets(PACKAGED / "public", PACKAGED / "uplot"),
        WebAssets(CHECKOUT / "public", CHECKOUT / "node_modules" / "uplot" / "dist"),
    ):
        if (assets.page / "index.html").is_file() and (assets.uplot / "uPlot.iife.min.js").is_file():
            return assets
    raise FileNotFoundError(
        f"dashboard files missing: neither {PACKAGED} (a wheel) nor {CHECKOUT} with uPlot in node_modules "
        f"(a checkout: run `npm ci` in {CHECKOUT}, as bash .ci/setup does)"
    )
