import jax

# float64 by default in the tests; float32 paths are exercised explicitly (see helpers.cast).
jax.config.update("jax_enable_x64", True)
