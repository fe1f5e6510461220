"""Host data to the device (`ctjax._convert`)."""

import numpy as np


def _compiles(run) -> list:
    """The programs XLA compiled while `run()` ran (`jax.monitoring`'s compile events)."""
    from jax._src import monitoring

    compiled = []

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            compiled.append(event)

    monitoring.register_event_duration_secs_listener(listen)
    try:
        run()
    finally:
        monitoring.unregister_event_duration_listener(listen)
    return compiled


def test_host_data_goes_to_the_device_without_a_compiled_program():
    """`on_device`: host arrays as `jnp.asarray` gives them (dtype canonicalised), without
    the program `jnp.asarray` compiles per shape (`lax.stage`); JAX arrays pass through."""
    import jax
    import jax.numpy as jnp

    from ctjax._convert import on_device

    host = np.arange(6.0).reshape(2, 3)
    for dtype in (None, np.float32, np.int32):
        got, want = on_device(host, dtype), jnp.asarray(host, dtype)
        assert got.dtype == want.dtype and got.shape == want.shape
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    assert isinstance(on_device([1, 2]), jax.Array) and on_device([1, 2]).shape == (2,)
    device = jnp.ones(3)
    assert on_device(device) is device
    assert jax.jit(lambda x: on_device(x, jnp.float32))(device).dtype == jnp.float32
    assert not _compiles(lambda: on_device(np.zeros((7, 11, 13))))


def test_lobe_weights_from_host_data_compile_no_program():
    """`as_float` and `as_rgb` of host data (NumPy arrays and scalars, Python ints) give what
    `jnp.asarray` and `jnp.broadcast_to` give, dtype and weak type included, without an
    eager JAX operation; a Python float stays weakly typed."""
    import jax
    import jax.numpy as jnp

    from ctjax._convert import as_float, as_rgb

    host = [np.float64(0.3), np.float32(0.5), np.arange(3.0), 2, True, np.int32(4), np.ones(3)]
    got = []
    assert not _compiles(lambda: got.extend((as_float(x), as_rgb(x)) for x in host))
    for x, (scalar, rgb) in zip(host, got, strict=True):
        want = jnp.asarray(x)
        want = want if jnp.issubdtype(want.dtype, jnp.floating) else want.astype(float)
        want_rgb = jnp.broadcast_to(want, (3,))
        for a, b in ((scalar, want), (rgb, want_rgb)):
            assert (a.dtype, a.weak_type, a.shape) == (b.dtype, b.weak_type, b.shape), x
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    weak = as_rgb(0.25)
    assert weak.weak_type and weak.shape == (3,) and isinstance(weak, jax.Array)
