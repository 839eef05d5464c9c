"""Differentiable forward operator for data assimilation: radiance images as a function of the cloud liquid water
content, with tangent-linear and adjoint operators and image misfits, a variational retrieval, the paper's
colour-ratio baseline and synthetic observations (docs/assimilation.md).

JAX is imported with this package: the operator runs the JAX march
(docs/decisions/0025-differentiable-forward-operator.md).
"""

from .alignment import AlignmentResult, align_clouds
from .colour_ratio import ColourRatioUpdate, colour_ratio_update
from .misfit import one_minus_r, rmse
from .observe import synthetic_observations
from .operator import ForwardOperator, forward_operator
from .retrieval import RetrievalResult, retrieve_liquid_water
from .setup import Observer

__all__ = ["AlignmentResult", "ColourRatioUpdate", "ForwardOperator", "Observer", "RetrievalResult", "align_clouds",
           "colour_ratio_update", "forward_operator", "one_minus_r", "retrieve_liquid_water", "rmse",
           "synthetic_observations"]
