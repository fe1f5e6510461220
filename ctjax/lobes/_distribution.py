"""Microfacet normal distributions, in the paper's normalisation.

The paper's Beckmann term (eq. 2) is `exp(-tan^2 a / s^2) / (s^2 cos^4 a)`, i.e. pi times the
textbook normalised distribution (the pi sits in the specular term's denominator instead).
Every distribution here follows that convention so that they are drop-in replacements for each
other in `Specular`.
"""

import abc

import equinox as eqx

from .._typing import Scalar


class AbstractDistribution(eqx.Module):
    """A microfacet distribution D(alpha), alpha = angle(N, H), paper normalisation."""

    @abc.abstractmethod
    def __call__(self, cos_alpha: Scalar) -> Scalar:
        """D at `cos_alpha` = N.H, in [1e-6, 1] (the caller floors it); finite and >= 0."""
