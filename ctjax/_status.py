"""How a solve ended: one public enumeration for every estimator, per fit or per pixel.

Like optimistix's `RESULTS`, with messages; unlike it, an `IntEnum` whose codes are plain
integers, so that a per-pixel status map is an ordinary integer array (saved in an NPZ,
counted with NumPy). Solvers' own results are converted with `Status.of_optimistix`, which
uses only optimistix's public API (comparison with its `RESULTS` items).
"""

import enum

import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ._typing import Array, Int


class Status(enum.IntEnum):
    """The end of one solve. `message` says it in words."""

    not_solved = -1
    successful = 0
    max_steps_reached = 1
    singular = 2
    nonfinite = 3
    diverged = 4
    failed = 5
    given = 6
    # The solve converged, but the data do not determine a parameter (`ctjax._determined`).
    at_bound = 7
    no_lobe = 8
    no_standard_error = 9
    unstable = 10
    misoriented = 11
    imprecise = 12
    brightness_off = 13

    @property
    def message(self) -> str:
        return _MESSAGES[self]

    @property
    def converged(self) -> bool:
        """The solver converged (or the value was given): the flags of what the data do
        not determine (`at_bound`, `no_lobe`, `no_standard_error`) count as converged."""
        return self in (Status.successful, Status.given, *_UNDETERMINED)

    @property
    def determined(self) -> bool:
        """Converged, and every parameter determined by the data: a measurement."""
        return self in (Status.successful, Status.given)

    @staticmethod
    def of_optimistix(result) -> Int[Array, "..."]:
        """Codes of optimistix results (`solution.result`, batched under `vmap` or not).

        Only the public comparison `result == optx.RESULTS.<name>` is used, so a release of
        optimistix that renumbers or adds results maps to `failed`, never to a wrong name.
        """
        code = jnp.asarray(Status.failed.value)
        for name, status in _FROM_OPTIMISTIX:
            item = getattr(optx.RESULTS, name, None)
            if item is not None:
                code = jnp.where(result == item, status.value, code)
        return code

    @classmethod
    def worst(cls, codes) -> "Status":
        """One status for many solves: successful only if every one is."""
        codes = np.asarray(codes).reshape(-1)
        codes = codes[codes != cls.not_solved]
        if codes.size == 0 or np.all(codes == cls.successful):
            return cls.successful
        return cls(int(codes[codes != cls.successful][0]))

    @classmethod
    def counts(cls, codes) -> dict[str, int]:
        """`converged`, `max_steps` and `failed` counts of solved pixels' codes."""
        codes = np.asarray(codes).reshape(-1)
        codes = codes[codes != cls.not_solved]
        converged = int(np.sum(codes == cls.successful))
        max_steps = int(np.sum(codes == cls.max_steps_reached))
        return {
            "converged": converged,
            "max_steps": max_steps,
            "failed": int(codes.size) - converged - max_steps,
        }


_UNDETERMINED = (
    Status.at_bound,
    Status.no_lobe,
    Status.no_standard_error,
    Status.unstable,
    Status.misoriented,
    Status.imprecise,
    Status.brightness_off,
)

_MESSAGES = {
    Status.not_solved: "not solved (no data at this pixel, or not in the solved set)",
    Status.successful: "converged",
    Status.max_steps_reached: "the solver ran out of steps before converging",
    Status.singular: "the linear system was singular (the data do not determine the unknowns)",
    Status.nonfinite: "a non-finite value (NaN or inf) was met",
    Status.diverged: "the iteration diverged",
    Status.failed: "the solver failed",
    Status.given: "given, not estimated",
    Status.at_bound: "converged with a parameter at the end of its search range: no "
    "measurement of it",
    Status.no_lobe: "converged, but no specular lobe is found (its weight cannot be told from "
    "0): its roughness is not determined",
    Status.no_standard_error: "converged, but a standard error could not be computed (the "
    "data do not constrain a parameter)",
    Status.unstable: "converged, but two halves of the frames disagree on a parameter: no "
    "measurement of it",
    Status.misoriented: "converged, but the highlights lie where one rotation of the normals "
    "would put N = H: the lobe is fitted about normals that misplace them, no measurement of "
    "it",
    Status.imprecise: "converged, but a roughness's standard error is over a quarter of its "
    "value: the data leave it anywhere from half to one and a half times it, no measurement of it",
    Status.brightness_off: "converged, but frames are brighter or darker than the other frames "
    "predict under the model (an exposure change or a falloff it lacks, which the lobe "
    "absorbs): no measurement of the lobe",
}

_FROM_OPTIMISTIX = (
    ("successful", Status.successful),
    ("max_steps_reached", Status.max_steps_reached),
    ("nonlinear_max_steps_reached", Status.max_steps_reached),
    ("singular", Status.singular),
    ("nonfinite", Status.nonfinite),
    ("nonlinear_divergence", Status.diverged),
)
