"""Real-time hygiene for the control loop process.

OpenBLAS (numpy's BLAS) starts one thread per core and spins them on every matrix product. In a 500 Hz loop
the products are tiny (NEXT's streaming LSTM: 50 x 256 @ 256 x 512): on a 2-core machine that is busy,
multi-threaded BLAS made one NEXT update 14 ms instead of 0.95 ms (measured). single_thread_blas() pins
BLAS to one thread: through the environment for libraries not loaded yet, and through OpenBLAS's own
set_num_threads for a numpy that is already imported.
"""

from __future__ import annotations

import ctypes
import glob
import os
import sys

_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_SYMBOLS = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
            "openblas_set_num_threads64_", "openblas_set_num_threads")


def single_thread_blas() -> bool:
    """Pin BLAS to one thread in this process. True when a loaded OpenBLAS was set (or none is loaded)."""
    for k in _ENV:
        os.environ[k] = "1"
    np = sys.modules.get("numpy")
    if np is None:
        return True
    libdir = os.path.join(os.path.dirname(os.path.dirname(np.__file__)), "numpy.libs")
    for path in glob.glob(os.path.join(libdir, "*openblas*")):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in _SYMBOLS:
            fn = getattr(lib, name, None)
            if fn is not None:
                fn(ctypes.c_int(1))
                return True
    return False
