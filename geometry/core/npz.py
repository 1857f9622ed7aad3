"""Byte-identical ``.npz`` archives.

``np.savez`` stamps the current time into every zip member, so equal arrays written twice give
different files; :func:`save_npz` writes the same ``.npy`` members with a fixed date and fixed
attributes.  ``np.load`` reads the result as usual.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["save_npz"]


def save_npz(path: str | Path, arrays: dict[str, ArrayLike]) -> Path:
    """Write ``arrays`` (name -> array, written in the order given) to a compressed ``.npz``.

    Parameters
    ----------
    path : output file.
    arrays : the members; each is stored as ``NAME.npy`` with its own dtype.

    Returns
    -------
    The path written.
    """
    out = Path(path)
    with zipfile.ZipFile(out, "w") as archive:
        for name, array in arrays.items():
            buffer = io.BytesIO()
            np.lib.format.write_array(buffer, np.ascontiguousarray(array), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.create_system = 3
            info.external_attr = 0o644 << 16
            archive.writestr(info, buffer.getvalue(), compresslevel=6)
    return out
