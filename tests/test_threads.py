"""hardware.threads.limit_threads: the one way to limit the numeric libraries' threads, given back."""

import os

import pytest
import torch
from threadpoolctl import threadpool_info

from hardware.threads import BLAS_ENV, limit_threads


def _blas_threads() -> list[int]:
    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


def test_a_limit_sets_each_library_and_close_gives_back_what_it_changed(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    torch_before, blas_before = torch.get_num_threads(), _blas_threads()
    with limit_threads(1, blas=True, torch=True, env=True) as lim:
        assert lim.n == 1 and torch.get_num_threads() == 1
        assert all(n == 1 for n in _blas_threads())
        assert all(os.environ[k] == "1" for k in BLAS_ENV)
    assert torch.get_num_threads() == torch_before and _blas_threads() == blas_before
    assert os.environ["OMP_NUM_THREADS"] == "3" and "OPENBLAS_NUM_THREADS" not in os.environ


def test_a_limit_touches_only_what_it_names():
    torch_before, blas_before = torch.get_num_threads(), _blas_threads()
    with limit_threads(1, torch=True):
        assert _blas_threads() == blas_before
    with limit_threads(1, blas=True):
        assert torch.get_num_threads() == torch_before
    with pytest.raises(ValueError):
        limit_threads(0, torch=True)
