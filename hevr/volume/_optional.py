"""Optional readers' packages (nibabel, pydicom, tifffile, …): import or say which extra."""

from __future__ import annotations

import importlib
from pathlib import Path
from types import ModuleType

from ..errors import MissingDependencyError

__all__ = ["require"]


def require(module: str, path: Path) -> ModuleType:
    """Import an optional dependency or explain which extra provides it."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingDependencyError(
            f"reading {path.name} needs the optional package '{module}', which is not installed: pip install 'hevr[io]'"
        ) from exc
