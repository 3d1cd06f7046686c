"""Where the configs (``conf/``) and the shipped models (``pretrained/``) are: beside the package in a clone of the
repository, or inside it (``neuralcol/_resources/``) in an installed wheel, which copies both folders there when it
is built (``setup.py``). The repository's layout stays as it is; code asks here instead of counting parent folders.
"""

from __future__ import annotations

from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
CHECKOUT = PACKAGE.parent  # the repository root in a clone (an editable install included)
PACKAGED = PACKAGE / "_resources"  # where a built wheel carries them

RESOURCES = ("conf", "pretrained")


def resource_dir(name: str) -> Path:
    """The folder ``name`` (``conf`` or ``pretrained``): the clone's if this package sits in one, else the copy the
    wheel carries. A folder found in neither place is returned as the clone's path (callers say what is missing)."""
    if name not in RESOURCES:
        raise ValueError(f"unknown resource folder {name!r}; one of {', '.join(RESOURCES)}")
    checkout = CHECKOUT / name
    if checkout.is_dir() and (CHECKOUT / "neuralcol" / "__init__.py").is_file():
        return checkout
    packaged = PACKAGED / name
    return packaged if packaged.is_dir() else checkout


def conf_dir() -> Path:
    """The Hydra configs (``conf/``)."""
    return resource_dir("conf")


def pretrained_dir() -> Path:
    """The shipped models (``pretrained/``)."""
    return resource_dir("pretrained")
