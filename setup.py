"""The wheel carries the configs and the shipped models: ``conf/`` and ``pretrained/`` are copied into
``neuralcol/_resources/`` when the package is built (``neuralcol.resources`` finds them there when there is no clone
around the package). Everything else is in pyproject.toml."""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent


class BuildWithResources(build_py):
    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            return  # an editable install reads them from the clone
        for name in ("conf", "pretrained"):
            src = ROOT / name
            if src.is_dir():
                shutil.copytree(src, Path(self.build_lib) / "neuralcol" / "_resources" / name, dirs_exist_ok=True,
                                ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))


setup(cmdclass={"build_py": BuildWithResources})
