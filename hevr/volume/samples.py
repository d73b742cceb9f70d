"""Real scans that every installation with the ``io`` extra reads offline (no download).

``hevr.sample_scan("mri")`` is the path of ``anatomical.nii``, which nibabel ships in its wheel
(MIT licence, nibabel's ``COPYING``): a crop of a real T1-weighted brain MRI around the lateral
ventricles, 33×41×25 voxels of 2 mm, int16, with its orientation (read into RAS+ by
:func:`hevr.read_scan`). Small enough to encrypt and render in seconds with a test key, real
enough to show what a scan looks like (anatomy, noise, a skewed value distribution). On the
command line it is the input ``sample:mri`` (as ``phantom:N`` is the phantom).
"""

from __future__ import annotations

from pathlib import Path

from ..core.validate import check_choice
from ..errors import MissingFileError
from ._optional import require

__all__ = ["SAMPLES", "sample_scan"]

# name -> (package, path inside it, what it is)
SAMPLES = {
    "mri": (
        "nibabel",
        "tests/data/anatomical.nii",
        "a crop of a real T1-weighted brain MRI, 33×41×25 voxels of 2 mm (nibabel's test data, MIT licence)",
    ),
}


def sample_scan(name: str = "mri") -> Path:
    """The path of a real scan shipped by an installed package (module docstring).

    Raises
    ------
    MissingDependencyError
        The package that ships it is not installed (``pip install 'hevr[io]'``).
    MissingFileError
        The package is installed without its data (a stripped build).

    Examples
    --------
    >>> sample_scan().name
    'anatomical.nii'
    """
    check_choice("name", name, tuple(SAMPLES))
    package, inside, what = SAMPLES[name]
    module = require(package, Path(inside))
    if module.__file__ is None:  # a namespace package: no folder of its own to hold the sample
        raise MissingFileError("name", f"the sample scan {name!r}: {what}", inside)
    path = Path(module.__file__).parent / inside
    if not path.is_file():
        raise MissingFileError("name", f"the sample scan {name!r}: {what}", path)
    return path
