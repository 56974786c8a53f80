"""How many threads the numeric libraries use, limited in one place: limit_threads(n, ...) returns the
limit, held by whoever needs it and given back by close() (or the end of a `with` block).

- blas: the BLAS already loaded in this process (numpy's OpenBLAS), through threadpoolctl. Why one thread
  beside a control loop: OpenBLAS starts one thread per core and spins them on every product; the loop's
  products are tiny (NEXT's streaming LSTM: 50 x 256 @ 256 x 512), and on a busy 2-core machine
  multi-threaded BLAS made one NEXT update 14 ms instead of 0.95 ms (measured).
- env: OPENBLAS/OMP/MKL_NUM_THREADS, for libraries loaded later in this process and its children.
- torch: torch's intra-op threads (torch.set_num_threads).

A trainer's own choice of threads (calibration/next/train.py, policies/training/train_threads.py pick_threads;
ThreadProbe switches them per batch) is not a limit and stays with the trainer.
"""

from __future__ import annotations

import os

BLAS_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


class ThreadLimit:
    """A limit in force until close(), which gives back what it changed (env, BLAS, torch)."""

    def __init__(self, n: int, *, blas: bool, torch: bool, env: bool):
        if int(n) < 1:
            raise ValueError(f"a thread limit needs at least 1 thread, got {n}")
        self.n = int(n)
        self._env_before = {k: os.environ.get(k) for k in BLAS_ENV} if env else None
        if env:
            os.environ.update({k: str(self.n) for k in BLAS_ENV})
        self._blas = None
        if blas:
            from threadpoolctl import threadpool_limits

            self._blas = threadpool_limits(limits=self.n, user_api="blas")
        self._torch_before: int | None = None
        if torch:
            import torch as _torch

            self._torch_before = _torch.get_num_threads()
            _torch.set_num_threads(self.n)

    def close(self) -> None:
        if self._blas is not None:
            self._blas.restore_original_limits()
            self._blas = None
        if self._torch_before is not None:
            import torch as _torch

            _torch.set_num_threads(self._torch_before)
            self._torch_before = None
        if self._env_before is not None:
            for k, v in self._env_before.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
            self._env_before = None

    def __enter__(self) -> ThreadLimit:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def limit_threads(n: int, *, blas: bool = False, torch: bool = False, env: bool = False) -> ThreadLimit:
    """Limit the libraries named to `n` threads each (module doc) until the returned limit is closed."""
    return ThreadLimit(n, blas=blas, torch=torch, env=env)
