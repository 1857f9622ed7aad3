"""Results of pure functions of arrays, kept for the next call with the same content.

A design asks some plans more than once on the same arrays (the hinge reliefs after the route,
before the solids and while building them; the string's openings for every length an output
states).  :class:`Memo` keeps the last few results keyed by a digest of the arguments' content
(:func:`content_key`: dtype, shape and bytes of each array), so a repeated call returns the
same object, and a call on other arrays computes afresh.  Callers treat what they get as
read-only.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable
from typing import Generic, TypeVar

import numpy as np

T = TypeVar("T")


def content_key(*parts: object) -> bytes:
    """A digest of ``parts``: arrays (and sequences of numbers) by dtype, shape and bytes,
    anything else by its ``repr`` (which for a frozen dataclass names every field)."""
    digest = hashlib.blake2b(digest_size=20)
    for part in parts:
        if isinstance(part, np.ndarray | list | tuple) and _numeric(part):
            array = np.ascontiguousarray(part)
            digest.update(f"{array.dtype.str}{array.shape}".encode())
            digest.update(array.tobytes())
        else:
            digest.update(repr(part).encode())
        digest.update(b"\x00")
    return digest.digest()


def _numeric(part: object) -> bool:
    try:
        return np.asarray(part).dtype.kind in "biuf"
    except ValueError:  # ragged
        return False


class Memo(Generic[T]):
    """The last ``size`` results of one function, by :func:`content_key` of its arguments."""

    def __init__(self, size: int = 4) -> None:
        self._size = size
        self._kept: OrderedDict[bytes, T] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: bytes, make: Callable[[], T]) -> T:
        """The result kept under ``key``, else ``make()`` kept under it."""
        with self._lock:
            if key in self._kept:
                self._kept.move_to_end(key)
                return self._kept[key]
        made = make()
        with self._lock:
            self._kept[key] = made
            while len(self._kept) > self._size:
                self._kept.popitem(last=False)
        return made

    def clear(self) -> None:
        with self._lock:
            self._kept.clear()
