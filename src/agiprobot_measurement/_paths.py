"""Where the package's data lives: config/, urdf/, parts/ in the source tree or the catkin install space.

Found by looking for the package manifest, not by a file's depth, so that modules can move and an installed
package (``<prefix>/lib/python3/dist-packages``, data in ``<prefix>/share/agiprobot_measurement``) works too.
``AGIPROBOT_MEASUREMENT_ROOT`` overrides the search.
"""

from __future__ import annotations

import os
from pathlib import Path

from agiprobot_measurement.errors import InternalError

PACKAGE_NAME = "agiprobot_measurement"


def _is_package_root(folder: Path) -> bool:
    manifest = folder / "package.xml"
    return (
        manifest.is_file() and (folder / "config").is_dir() and f"<name>{PACKAGE_NAME}</name>" in manifest.read_text()
    )


def find_package_root(start: Path | None = None) -> Path:
    """The folder holding this package's ``package.xml`` and ``config/``."""
    override = os.environ.get("AGIPROBOT_MEASUREMENT_ROOT")
    if override:
        return Path(override).expanduser().resolve()
    here = (start or Path(__file__)).resolve()
    for folder in here.parents:
        if _is_package_root(folder):
            return folder
        share = folder / "share" / PACKAGE_NAME
        if _is_package_root(share):
            return share
    raise InternalError(f"cannot find the {PACKAGE_NAME} package root (package.xml + config/) above {here}")


PACKAGE_ROOT = find_package_root()
CONFIG_DIR = PACKAGE_ROOT / "config"
URDF_DIR = PACKAGE_ROOT / "urdf"
PARTS_DIR = PACKAGE_ROOT / "parts"
