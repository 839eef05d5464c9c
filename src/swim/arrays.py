"""The array library of a computation: numpy, or ``jax.numpy`` where the inputs are JAX arrays.

The optics, surface and table functions are shared by the numba kernel's host code, which hands them numpy
arrays, and by the JAX kernels, which call them on traced JAX arrays inside ``jax.jit`` (and on which
gradients are taken). Each such function asks :func:`array_namespace` for the library of its inputs and
computes with it, so a CPU render never imports JAX (docs/decisions/0011-jax-only-where-it-runs.md).

Both libraries implement the Python array API standard (https://data-apis.org/array-api/): an array's
``__array_namespace__()`` names its library, and JAX's tracers answer ``jax.numpy`` too.
"""

from __future__ import annotations

import numpy as np


def array_namespace(*values):
    """The array library of ``values``: ``jax.numpy`` if any of them is a JAX array or tracer, else numpy.

    Python scalars, lists, numpy arrays and numpy scalars count as numpy. Never imports JAX itself: a JAX
    array exists only once JAX is imported.

    Parameters
    ----------
    *values : array_like
        The inputs of a computation, of any shapes.

    Returns
    -------
    module
        ``numpy`` or ``jax.numpy``.
    """
    for value in values:
        namespace = getattr(value, "__array_namespace__", None)
        if namespace is not None and not isinstance(value, (np.ndarray, np.generic)):
            return namespace()
    return np


def is_jax(xp) -> bool:
    """Whether the array library ``xp`` (from :func:`array_namespace`) is ``jax.numpy``."""
    return xp is not np


def erfc(x):
    """The complementary error function, elementwise, in the library of ``x`` (scipy's for numpy input)."""
    xp = array_namespace(x)
    if is_jax(xp):
        from jax.scipy.special import erfc as jax_erfc

        return jax_erfc(x)
    from scipy.special import erfc as scipy_erfc

    return scipy_erfc(x)
