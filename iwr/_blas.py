"""Keep BLAS to one thread around small dense linear algebra."""

from __future__ import annotations

import contextlib
from typing import Any


def single_thread() -> Any:
    """A context in which BLAS/LAPACK use one thread.

    The matrices of this package are small (hundreds of rows, 58 columns). OpenBLAS still spreads
    them over its threads, whose spinning makes an SVD of a 600 x 58 matrix a hundred times slower
    (a second instead of milliseconds) on a machine whose cores are busy.
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")
