"""Maths whose result for one proposal does not depend on the proposals computed with it.

One proposal scored alone must get the bits it gets among thousands (``score_vocabulary``). numpy's elementwise
functions and the compiled simulator (``simulation.py``) give that by construction; a BLAS product over all rows
does not: it rounds a row differently depending on how many rows come with it, so :func:`row_products` multiplies
each row by the matrix on its own.
"""

import numpy as np

#: a quantity of many proposals (an array) or of one (a Python float)
Values = np.ndarray | float


def row_products(values: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """``values (..., K) @ matrix (K, M)`` with every row ``values[..., :]`` multiplied on its own (a stack of
    ``(1, K) @ (K, M)`` products), so its result does not depend on the rows beside it."""
    return (np.asarray(values)[..., None, :] @ matrix)[..., 0, :]
