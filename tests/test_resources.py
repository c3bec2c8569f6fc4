"""Process resources: the scoped one-thread BLAS of the KD loops leaves the caller's BLAS setting as it found it,
also when blocks nest or run from several threads at once, and KD results do not depend on it."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from threadpoolctl import ThreadpoolController

from kdfaces.resources import single_threaded_blas


def _blas_threads() -> list[int]:
    return [lib["num_threads"] for lib in ThreadpoolController().info() if lib["user_api"] == "blas"]


def test_single_threaded_blas_nests_and_restores_the_callers_setting():
    if not _blas_threads():
        pytest.skip("numpy is linked to no BLAS that threadpoolctl can see")
    with ThreadpoolController().limit(limits=2, user_api="blas"):  # the caller's own setting
        with single_threaded_blas():
            assert set(_blas_threads()) == {1}
            with single_threaded_blas():
                assert set(_blas_threads()) == {1}
            assert set(_blas_threads()) == {1}  # the outer block still holds it
        assert set(_blas_threads()) == {2}
        barrier = threading.Barrier(3)

        def worker():
            with single_threaded_blas():
                barrier.wait()  # all three inside at once
                barrier.wait()

        threads = [threading.Thread(target=worker) for _ in range(3)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert set(_blas_threads()) == {2}  # overlapping blocks from threads restore the setting once, at the end


def test_an_error_inside_the_block_restores_the_setting():
    if not _blas_threads():
        pytest.skip("numpy is linked to no BLAS that threadpoolctl can see")
    before = _blas_threads()
    with pytest.raises(ValueError), single_threaded_blas():
        np.ones((64, 64)) @ np.ones((64, 64))
        raise ValueError("inside")
    assert _blas_threads() == before
