"""numba's on-disk kernel cache, safe for several processes that compile at once.

The kernels are compiled with ``cache=True`` and kept beside their sources, shared by every
process of a checkout: the nodes of a fleet, the test suite's parallel workers (a suite run
adds overloads to about a dozen kernels: float64 depth next to float32, an 'A' layout next to
'C'). numba 0.68 saves a new overload by reading the kernel's index, taking the first data-file
number the index does not name, writing the index and then the data. Two processes saving two
overloads of one kernel at once can take the same number; the index then names a file that
holds the other overload's machine code, and every later process that loads it runs that code
on arguments of another type (numba/numba#10128 is the same kind of race, between a function
and its gufunc). Every save here holds an exclusive ``flock`` on a file beside the index from
reading it to writing the data, so the second saver sees the first one's number.

Kernel modules take ``njit`` from here, which installs the lock before any kernel can compile.
"""

from __future__ import annotations

import fcntl
from typing import Any

from numba import njit
from numba.core.caching import IndexDataCacheFile

__all__ = ["njit"]

#: numba's own save, kept on the class so that a second import of this module wraps it again
#: instead of wrapping the wrapper (a nested lock on the same file would wait for itself)
_unlocked_save = getattr(IndexDataCacheFile, "_unlocked_save", IndexDataCacheFile.save)


def _save_under_lock(self: IndexDataCacheFile, key: Any, data: Any) -> None:
    """``IndexDataCacheFile.save`` with the kernel's index locked against other processes (a
    lock that cannot be had leaves numba's save as it is: a kernel still compiles)."""
    try:
        lock = open(f"{self._index_path}.lock", "a")
    except OSError:
        _unlocked_save(self, key, data)
        return
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)         # released when the file closes
        _unlocked_save(self, key, data)


IndexDataCacheFile._unlocked_save = _unlocked_save  # type: ignore[attr-defined]
IndexDataCacheFile.save = _save_under_lock  # type: ignore[method-assign]
