"""Build hook: the wheel carries its git commit (gcs/_build.json) and the dashboard (web/public
and uPlot from web/package-lock.json) inside the package as gcs/server/web, so an installed gcs
needs neither npm nor the source tree.
Everything else about the package is in pyproject.toml."""

import json
import shutil
import subprocess
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
WEB = ROOT / "web"
UPLOT_FILES = ("uPlot.iife.min.js", "uPlot.min.css", "LICENSE")


def uplot_dist() -> Path:
    """web/node_modules/uplot, installed from the lock file if it is not there yet."""
    uplot = WEB / "node_modules" / "uplot"
    if not (uplot / "dist" / "uPlot.iife.min.js").is_file():
        subprocess.run(["npm", "ci", "--no-audit", "--no-fund", "--loglevel=error"], cwd=WEB, check=True)
    return uplot


def commit() -> str | None:
    """The checkout's git commit ("+dirty" with uncommitted changes), None outside git."""
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    if head.returncode != 0:
        return None
    status = ["git", "status", "--porcelain", "--untracked-files=no"]
    dirty = subprocess.run(status, cwd=ROOT, capture_output=True, text=True).stdout.strip()
    return head.stdout.strip() + ("+dirty" if dirty else "")


class BuildWithDashboard(build_py):
    def run(self) -> None:
        super().run()
        if self.editable_mode:
            return  # an editable install serves web/ and reads its commit from the checkout itself
        (Path(self.build_lib) / "gcs" / "_build.json").write_text(json.dumps({"commit": commit()}))
        target = Path(self.build_lib) / "gcs" / "server" / "web"
        shutil.rmtree(target, ignore_errors=True)
        shutil.copytree(WEB / "public", target / "public")
        uplot = uplot_dist()
        (target / "uplot").mkdir(parents=True)
        for name in UPLOT_FILES:
            source = uplot / name if name == "LICENSE" else uplot / "dist" / name
            shutil.copy2(source, target / "uplot" / name)


setup(cmdclass={"build_py": BuildWithDashboard})
