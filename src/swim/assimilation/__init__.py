"""Differentiable forward operator for data assimilation: radiance images as a function of the cloud liquid water
content, with tangent-linear and adjoint operators and image misfits (docs/assimilation.md).

JAX is imported with this package: the operator runs the JAX march
(docs/decisions/0025-differentiable-forward-operator.md).
"""

from .misfit import one_minus_r, rmse
from .operator import ForwardOperator, forward_operator
from .setup import Observer

__all__ = ["ForwardOperator", "Observer", "forward_operator", "one_minus_r", "rmse"]
