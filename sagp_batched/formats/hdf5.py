"""The one HDF5 writer: every grasp file this project writes is a mapping of dataset names to values handed here.

A value becomes one dataset of the name (``"grasps/transforms"``; the groups are made on the way):

- a `numpy.ndarray`, a `float`, an `int`: a dataset of its dtype and shape (a Python float is float64, a Python
  int int64, both scalar);
- a `str`: a scalar UTF-8 variable-length string;
- a `list` of `str`: a (N,) UTF-8 variable-length string dataset, the dtype ACRONYM's strings read as.
"""
from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Any, BinaryIO, Mapping

import numpy as np


def _write(target: str | Path | BinaryIO, datasets: Mapping[str, Any]) -> None:
    import h5py

    with h5py.File(target, "w") as f:
        for name, value in datasets.items():
            if isinstance(value, list):
                f.create_dataset(name, data=np.array(value, dtype=object), dtype=h5py.string_dtype())
            else:
                f[name] = value


def hdf5_bytes(datasets: Mapping[str, Any]) -> bytes:
    """The bytes of an HDF5 file holding ``datasets`` (name -> value): for a file that travels before it is written
    (a study worker's, written by the driver)."""
    buffer = io.BytesIO()
    _write(buffer, datasets)
    return buffer.getvalue()


def write_hdf5(path: Path, datasets: Mapping[str, Any]) -> None:
    """An HDF5 file holding ``datasets`` (name -> value) at ``path``, replaced atomically: a reader finds the old file
    or the new one, never part of one."""
    temporary = path.with_name(path.name + ".tmp")
    _write(temporary, datasets)
    os.replace(temporary, path)
