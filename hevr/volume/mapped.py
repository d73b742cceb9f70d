"""Memory-mapped inputs read inside the tasks: a memmap goes into a task graph as its file's
name and byte layout, never as its voxels.

Why
---
``dask.array.from_array(np.memmap(...))`` puts the array object into the graph, and pickling
a memmap pickles *all of its data*: a 10 GiB scan became a 10 GiB message to the scheduler,
and a volume larger than the machine's memory could not be encrypted at all. The loaders
return uncompressed data (``.npy``, ``.raw``, raw NRRD, uncompressed NIfTI, TIFF) as
read-only memory maps, often as reoriented views (transposed, flipped:
:mod:`hevr.volume.orientation`). :func:`file_backed` describes such a view exactly — file
name, byte offset of element (0, 0, 0), shape, strides (negative for flipped axes), dtype —
as a small :class:`MappedFile` that pickles as that description. Each task maps the file
again and copies out only its own brick, so a worker holds one brick of plaintext at a
time, whatever the volume's size.
"""

from __future__ import annotations

import mmap
import os
from typing import Any

import dask.array
import numpy as np

__all__ = ["MappedFile", "file_backed", "task_array"]


class MappedFile:
    """A read-only array window onto a file: ``numpy``-style ``shape``/``dtype``/``[...]``.

    Parameters
    ----------
    filename : str
        The file (absolute path: tasks may run in another working directory).
    offset : int
        Byte position in the file of element (0, 0, 0) (the highest address of a flipped axis).
    shape, strides : tuple of int
        As numpy's; strides in bytes, negative for flipped axes.
    dtype : numpy dtype
        The voxel type in the file, with its byte order. The window's own ``dtype`` is its
        native-order twin: what ``[...]`` returns (a big-endian file is swapped in the copy
        each task makes, never read whole).

    Examples
    --------
    >>> import tempfile, os, pickle
    >>> p = os.path.join(tempfile.mkdtemp(), "v.raw")
    >>> np.arange(24, dtype=np.int16).tofile(p)
    >>> m = np.memmap(p, np.int16, "r", shape=(2, 3, 4))[:, ::-1]
    >>> src = pickle.loads(pickle.dumps(file_backed(m)))
    >>> bool((src[1, :2] == m[1, :2]).all()), len(pickle.dumps(src)) < 400
    (True, True)
    """

    def __init__(
        self, filename: str, offset: int, shape: tuple[int, ...], strides: tuple[int, ...], dtype: Any
    ) -> None:
        self.filename, self.offset = str(filename), int(offset)
        self.shape, self.strides = tuple(int(s) for s in shape), tuple(int(s) for s in strides)
        self.file_dtype = np.dtype(dtype)
        self.dtype = self.file_dtype.newbyteorder("=")
        self.ndim = len(self.shape)

    def __reduce__(self) -> tuple:
        return MappedFile, (self.filename, self.offset, self.shape, self.strides, self.file_dtype)

    def __repr__(self) -> str:
        return f"MappedFile({self.filename!r}, shape={self.shape}, dtype={self.dtype})"

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    def __getitem__(self, index: Any) -> np.ndarray:
        """A copy of ``array[index]`` in native byte order: the mapping is closed again when the
        copy is made."""
        raw = np.memmap(self.filename, dtype=np.uint8, mode="r")
        try:
            view = np.ndarray(self.shape, self.file_dtype, buffer=raw, offset=self.offset, strides=self.strides)
            return np.array(view[index], dtype=self.dtype)
        finally:
            del raw


def file_backed(vol: Any) -> MappedFile | None:
    """The :class:`MappedFile` behind a read-only ``np.memmap`` (or a view of one), else ``None``.

    Writable maps are not described: their contents may change under the tasks.
    """
    mm = getattr(vol, "_mmap", None)  # numpy's mmap.mmap under the array (private: not in its stubs)
    if not isinstance(vol, np.memmap) or mm is None or vol.flags.writeable:
        return None
    filename = getattr(vol, "filename", None)
    if not filename or not os.path.isfile(filename):
        return None
    base = np.frombuffer(mm, dtype=np.uint8)
    start = int(vol.offset) - int(vol.offset) % mmap.ALLOCATIONGRANULARITY  # where numpy mapped from
    pos = int(vol.__array_interface__["data"][0]) - int(base.ctypes.data) + start
    return MappedFile(os.path.abspath(filename), pos, vol.shape, vol.strides, vol.dtype)


def task_array(vol: Any, brick: tuple[int, int, int], name: str) -> Any:
    """``vol`` as the tasks should read it, in native byte order: a read-only memory map
    becomes a dask array named ``name`` whose tasks map the file and read their own brick
    (the graph holds the file's name and layout, never the voxels); any other array of
    another byte order (``>i2``, ``>f8`` of some NRRD and raw files) a dask array that swaps
    each brick inside its task; anything else is returned unchanged.

    >>> v = np.arange(8, dtype=">i2").reshape(2, 2, 2)
    >>> t = task_array(v, (1, 2, 2), "x")
    >>> t.dtype.isnative, t.compute().tolist() == v.tolist()
    (True, True)
    """
    src = file_backed(vol)
    if src is not None:
        return dask.array.from_array(src, chunks=brick, name=name, lock=False, meta=np.empty((0, 0, 0), src.dtype))
    dtype = np.dtype(vol.dtype)
    if dtype.isnative:
        return vol
    if not isinstance(vol, dask.array.Array):
        vol = dask.array.from_array(vol, chunks=brick, name=name)
    return vol.astype(dtype.newbyteorder("="))
