import equinox as eqx

from .._candidate import AbstractCandidate, with_lobes
from .._convert import POSITIVE, as_float, check_positive, check_shape, named
from .._typing import Array, Float, Scalar
from ._beckmann import Beckmann
from ._distribution import AbstractDistribution


class GGX(AbstractDistribution):
    """GGX / Trowbridge-Reitz distribution, `a^2 / (cos^2 t (a^2 - 1) + 1)^2`.

    Normalised like the paper's Beckmann (pi times the textbook density), so that both peak at
    `1 / roughness^2` and are interchangeable inside `Specular`. GGX has much longer tails than
    Beckmann: a "missing effect" the diagnostics can detect.

    **Arguments:**

    - `alpha`: GGX roughness, > 0 (comparable to Beckmann's sigma near the peak).
    """

    alpha: Float[Array, ""] = eqx.field(converter=as_float, metadata=named("alpha", POSITIVE))

    def __check_init__(self):
        check_shape("GGX", "alpha", self.alpha, ())
        check_positive("GGX", "alpha", self.alpha)

    def __call__(self, cos_alpha: Scalar) -> Scalar:
        a2 = self.alpha * self.alpha
        cos2 = cos_alpha * cos_alpha
        # cos^2 (a^2 - 1) + 1 written as sin^2 + a^2 cos^2: no cancellation to 0 in float32
        # at the peak of a sharp lobe, and >= a^2 cos^2 > 0.
        denominator = (1 - cos2) + a2 * cos2
        # (a / den)^2, not a^2 / den^2: den^2 of a sharp lobe's peak is ~a^4, which flushes
        # to 0 in float32 (and its square in the backward pass too).
        ratio = self.alpha / denominator
        return ratio * ratio


class GGXCandidate(AbstractCandidate):
    """GGX's longer tails instead of Beckmann, at the same roughness."""

    name = "ggx"

    def __call__(self, model, context):
        def swap(lobe):
            distribution = getattr(lobe, "distribution", None)
            if not isinstance(distribution, Beckmann):
                return lobe
            return eqx.tree_at(lambda l: l.distribution, lobe, GGX(distribution.sigma))

        return [with_lobes(model, swap)]

    def add_synth_arguments(self, group):
        group.add_argument("--ggx", action="store_true", help="GGX instead of Beckmann")

    def synth_value(self, args):
        return True if args.ggx else None

    def synthesize(self, model, value, context):
        return self(model, context)[0]
