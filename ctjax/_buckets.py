"""Sample counts padded to a few sizes, so that captures share compiled programs.

XLA compiles a program per array shape. Every capture has its own number of usable pixels
or tracked points, so without padding each new capture (and each test) compiles every
fitter again: ~1 s per fitter on the CPU, more than the fit itself on small captures, and
paid again by every CLI command on a new capture (the persistent cache matches shapes).
Padded to the next size of the sequence 256, 384, 512, 768, 1024, ... (2^k and 3 2^(k-1),
at most a third more work), captures of similar size share one program.

Padding repeats the last sample (a valid one: finite everywhere) and the fitters weight
the padded rows by 0 (`mask`), so results do not depend on the padding.
"""

import jax
import jax.numpy as jnp
import numpy as np

from ._convert import on_device

SMALLEST = 256


def bucket(n: int) -> int:
    """The padded length of `n` samples: the smallest 2^k or 3 2^(k-1) >= n (at least
    `SMALLEST`)."""
    if n <= SMALLEST:
        return SMALLEST
    power = 1 << (int(n) - 1).bit_length()  # smallest 2^k >= n
    three_quarters = 3 * power // 4
    return three_quarters if three_quarters >= n else power


def pad_leading(tree, n: int, size: int):
    """Every array leaf of `tree` whose leading axis has length `n`, padded to `size` by
    repeating its last entry (NumPy leaves stay NumPy, JAX leaves stay JAX).

    Concrete JAX arrays are padded in NumPy: eager `jnp` ops compile one small program per
    shape, which costs more than the copy."""
    if size == n or n == 0:
        return tree

    def pad(leaf):
        if not hasattr(leaf, "shape") or leaf.ndim == 0 or leaf.shape[0] != n:
            return leaf
        if isinstance(leaf, jax.core.Tracer):
            return jnp.concatenate([leaf, jnp.repeat(leaf[-1:], size - n, axis=0)])
        host = np.asarray(leaf)
        host = np.concatenate([host, np.repeat(host[-1:], size - n, axis=0)])
        return host if isinstance(leaf, np.ndarray) else on_device(host)

    return jax.tree.map(pad, tree)


def padded(tree, n: int):
    """`(tree padded to bucket(n), mask)`: mask (bucket(n),) is True on the `n` real rows."""
    size = bucket(n)
    mask = np.arange(size) < n
    return pad_leading(tree, n, size), mask
