"""Programs kept between processes (`ctjax._programs`): a kept program is loaded, not
traced again, and gives the same result; anything the key cannot cover is not kept."""

import jax.numpy as jnp
import numpy as np
import pytest

import ctjax
from ctjax import _programs
from ctjax._camera import Camera
from ctjax.estimation import PAPER
from ctjax.estimation._dense_maps import _frame_columns
from ctjax.lights import ColocatedLight
from ctjax.lobes import Lambertian


@pytest.fixture
def kept(tmp_path):
    folder = tmp_path / "programs"
    _programs.keep_programs(folder)
    yield folder
    _programs.keep_programs(None)


def _frame(height=12, width=16, seed=0):
    rng = np.random.default_rng(seed)
    normals = rng.normal(size=(height, width, 3)) * 0.2 + np.array([0.0, 0.0, -1.0])
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    depth = 60.0 + rng.uniform(0, 5, (height, width))
    depth[0, 0] = np.nan  # a pixel without geometry
    camera = Camera(fx=20.0, fy=20.0, cx=width / 2, cy=height / 2, width=width, height=height)
    return camera, jnp.asarray(normals), jnp.asarray(depth)


def _renamed_stub(original):
    """A function the key takes for `original` that fails if it is ever traced."""

    def stub(*args, **kwargs):
        raise AssertionError("a kept program was traced again")

    stub.__module__, stub.__qualname__ = original.__module__, original.__qualname__
    return stub


def test_a_kept_program_is_loaded_without_tracing_and_gives_the_same_result(kept):
    camera, normals, depth = _frame()
    brdf = PAPER.build(jnp.array([0.25]))
    direct = _frame_columns.__wrapped__  # the undecorated function
    expected = [
        np.asarray(a)
        for a in _programs.eqx.filter_jit(direct)(brdf, ColocatedLight(), camera, normals, depth)
    ]
    first = _frame_columns(brdf, ColocatedLight(), camera, normals, depth)
    assert len(list(kept.glob("*.program"))) == 1
    # A new process: a fresh wrapper, with code that must not run.
    reloaded = _programs.persistent_jit(_renamed_stub(direct))
    again = reloaded(brdf, ColocatedLight(), camera, normals, depth)
    for a, b, c in zip(expected, first, again, strict=True):
        np.testing.assert_allclose(np.asarray(b), a, rtol=1e-12)
        np.testing.assert_array_equal(np.asarray(c), np.asarray(b))
    # Another weight changes only arrays: the same program.
    _frame_columns(PAPER.build(jnp.array([0.4])), ColocatedLight(), camera, normals, depth)
    assert len(list(kept.glob("*.program"))) == 1


def test_other_shapes_or_static_arguments_are_other_programs(kept):
    camera, normals, depth = _frame()
    brdf = PAPER.build(jnp.array([0.25]))
    _frame_columns(brdf, ColocatedLight(), camera, normals, depth)
    lambertian = ctjax.BRDF(Lambertian(jnp.ones(3)))  # another structure: another program
    _frame_columns(lambertian, ColocatedLight(), camera, normals, depth)
    small = _frame(8, 10)
    _frame_columns(brdf, ColocatedLight(), *small)
    assert len(list(kept.glob("*.program"))) == 3


def test_a_damaged_program_is_exported_again(kept):
    camera, normals, depth = _frame()
    brdf = PAPER.build(jnp.array([0.25]))
    first = np.asarray(_frame_columns(brdf, ColocatedLight(), camera, normals, depth)[0])
    (path,) = kept.glob("*.program")
    path.write_bytes(b"not a program")
    fresh = _programs.persistent_jit(_frame_columns.__wrapped__)
    again = np.asarray(fresh(brdf, ColocatedLight(), camera, normals, depth)[0])
    np.testing.assert_array_equal(again, first)
    assert path.read_bytes() != b"not a program"


def test_code_the_key_does_not_cover_is_never_kept(kept):
    with pytest.raises(_programs._Unkeyable):
        _programs._keyed(lambda x: x)  # a closure may hold anything
    with pytest.raises(_programs._Unkeyable):
        _programs._keyed(object())  # shown by address

    class UserLobe(Lambertian):  # user code: not in ctjax's digest
        pass

    with pytest.raises(_programs._Unkeyable):
        _programs._keyed(UserLobe)
    assert _programs._keyed(_frame_columns.__wrapped__).startswith("ctjax.")
    assert _programs._keyed((1, 2.5, "a", None)) == "tuple(1,2.5,'a',None)"


def test_off_without_a_folder(tmp_path):
    camera, normals, depth = _frame()
    brdf = PAPER.build(jnp.array([0.25]))
    _programs.keep_programs(None)
    _frame_columns(brdf, ColocatedLight(), camera, normals, depth)
    assert not list(tmp_path.rglob("*.program"))
