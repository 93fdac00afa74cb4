"""Build steps that pyproject.toml cannot state: ship the defaults and the panel's uPlot inside the package.

- config/ (station files, procedure files, EDS, instrument files, twins, panel.toml) is copied into the wheel as
  station/_config, data of the station package (found by station.defaults): a plain install has the import names
  station, drivers, procedures and web, nothing else;
- uPlot (the panel's plots) is copied from the npm package (web/node_modules/uplot, installed by web/setup.sh
  or, when missing, by `npm ci` here) into web/vendor/uplot: minified assets are never committed.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
CONFIG_DATA = Path("station") / "_config"  # under the build directory
CONFIG_SUFFIXES = {".toml", ".eds"}
UPLOT_FILES = ("uPlot.iife.min.js", "uPlot.min.css", "uPlot.esm.js")
UPLOT_DIST = ROOT / "web" / "node_modules" / "uplot" / "dist"


def _uplot_dist() -> Path:
    if not (UPLOT_DIST / UPLOT_FILES[0]).is_file():
        try:
            subprocess.run(["npm", "ci", "--no-audit", "--no-fund", "--loglevel=error"], cwd=ROOT / "web", check=True)
        except (OSError, subprocess.CalledProcessError) as exc:
            raise SystemExit(
                f"setup.py: the panel needs uPlot from npm (web/package.json); `npm ci` in web/ failed: {exc}"
            ) from exc
    return UPLOT_DIST


class BuildWithAssets(build_py):
    """build_py, then the shipped defaults and uPlot into the build directory."""

    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False):
            return  # an editable install reads config/ and web/node_modules from the source tree
        target = Path(self.build_lib)
        config = target / CONFIG_DATA
        if config.exists():
            shutil.rmtree(config)
        for path in sorted((ROOT / "config").rglob("*")):
            if path.is_file() and path.suffix in CONFIG_SUFFIXES:
                dest = config / path.relative_to(ROOT / "config")
                dest.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(path, dest)
        vendor = target / "web" / "vendor" / "uplot"
        vendor.mkdir(parents=True, exist_ok=True)
        dist = _uplot_dist()
        for name in UPLOT_FILES:
            shutil.copy2(dist / name, vendor / name)


setup(cmdclass={"build_py": BuildWithAssets})
