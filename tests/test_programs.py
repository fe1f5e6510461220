"""Programs kept between processes (`ctjax._programs`): a kept program is loaded, not
traced again, and gives the same result; anything the key cannot cover is not kept. Kept
programs are data (no pickle), and a cache that another user can write is not used."""

import fractions
import json
import os
import pickle
import re
import stat
import subprocess
import sys
import threading
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ctjax
from ctjax import _performance, _private_files, _programs, _static_data
from ctjax._camera import Camera
from ctjax._status import Status
from ctjax.estimation import PAPER
from ctjax.estimation._dense_maps import _frame_columns
from ctjax.lights import ColocatedLight
from ctjax.lobes import Lambertian


@pytest.fixture
def kept(tmp_path, monkeypatch):
    folder = tmp_path / "programs"
    _programs.keep_programs(folder)
    monkeypatch.setattr(_private_files, "_WARNED", [False])  # the warning once per test
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


def test_the_first_process_runs_the_program_as_later_ones_read_it(kept, monkeypatch):
    """On a miss the program is run from the bytes just written, as a later process reads
    them: a freshly exported program can lower to another module than the one read back
    (XLA folds it on reading), which then misses JAX's compilation cache, and the second
    `ctjax fit` of a 320x256 x 5 capture compiled four programs again (8.7 s; 2.9 s warm)."""
    camera, normals, depth = _frame()
    read, program = [], _programs._program
    monkeypatch.setattr(
        _programs, "_program", lambda blob, *a: read.append(blob) or program(blob, *a)
    )
    _frame_columns(PAPER.build(jnp.array([0.25])), ColocatedLight(), camera, normals, depth)
    (written,) = kept.glob("*.program")
    assert read == [written.read_bytes()]


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
    with pytest.raises(_static_data.Unkeyable):
        _static_data.keyed(lambda x: x)  # a closure may hold anything
    with pytest.raises(_static_data.Unkeyable):
        _static_data.keyed(object())  # shown by address

    class UserLobe(Lambertian):  # user code: not in ctjax's digest
        pass

    with pytest.raises(_static_data.Unkeyable):
        _static_data.keyed(UserLobe)
    assert _static_data.keyed(_frame_columns.__wrapped__).startswith("ctjax.")
    assert _static_data.keyed((1, 2.5, "a", None)) == "tuple(1,2.5,'a',None)"


def test_off_without_a_folder(tmp_path):
    camera, normals, depth = _frame()
    brdf = PAPER.build(jnp.array([0.25]))
    _programs.keep_programs(None)
    _frame_columns(brdf, ColocatedLight(), camera, normals, depth)
    assert not list(tmp_path.rglob("*.program"))


def _fresh_call(brdf, camera, normals, depth):
    """`_frame_columns` as a new process runs it: a fresh wrapper, nothing loaded yet."""
    fresh = _programs.persistent_jit(_frame_columns.__wrapped__)
    return [np.asarray(a) for a in fresh(brdf, ColocatedLight(), camera, normals, depth)]


@pytest.fixture
def loads(monkeypatch):
    """The programs read back from files (`_programs._load` calls that found one)."""
    done = []
    load = _programs._load

    def spy(*args):
        found = load(*args)
        if found is not None:
            done.append(found)
        return found

    monkeypatch.setattr(_programs, "_load", spy)
    return done


def test_a_kept_program_is_data_in_the_documented_format(kept, loads):
    camera, normals, depth = _frame()
    brdf = PAPER.build(jnp.array([0.25]))
    first = [np.asarray(a) for a in _frame_columns(brdf, ColocatedLight(), camera, normals, depth)]
    (path,) = kept.glob("*.program")
    magic, header, exported = path.read_bytes().split(b"\n", 2)
    assert magic == b"ctjax-program 2"
    header = json.loads(header)
    assert header["key"] == path.stem
    assert jax.export.deserialize(bytearray(exported)).out_avals  # jax.export's own bytes
    again = _fresh_call(brdf, camera, normals, depth)
    assert len(loads) == 1  # read back from the file, not traced again
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(b, a)


def test_output_skeletons_are_written_in_a_closed_vocabulary():
    field = ctjax.LightField(jnp.ones((2, 3, 3)) / np.sqrt(3.0), method="linear")
    model = jax.tree.map(lambda _: _static_data.Array(), field)
    skeleton = (
        model,
        {"a": 0.5, "b": [1, "x", None, True, float("nan")]},
        Status.at_bound,
        ctjax.LightField,  # a class of ctjax's
        _performance.compilation_cache_dir,  # a function of ctjax's
        (),
    )
    data = _static_data.skeleton_data(skeleton)
    text = json.dumps(data)
    again = _static_data.read_skeleton(json.loads(text))
    assert jax.tree.structure(again) == jax.tree.structure(skeleton)
    assert again[0].method == "linear" and isinstance(again[0].directions, _static_data.Array)
    assert again[2] is Status.at_bound and again[3] is ctjax.LightField
    assert again[4] is _performance.compilation_cache_dir
    assert "equinox._module._flatten:MISSING" in text  # equinox's own static data

    class UserLobe(Lambertian):  # user code: not kept, whatever its name
        pass

    for other in [lambda: 0, UserLobe, object(), fractions.Fraction(1, 3), print, os.system]:
        with pytest.raises(_static_data.Unkeyable):
            _static_data.skeleton_data((model, other))


@pytest.mark.parametrize(
    "data",
    [
        {"node": "os:system", "aux": None, "children": []},  # not a library of ctjax's
        {"node": "ctjax._programs:os.system", "aux": None, "children": []},  # imported there
        {"node": "ctjax._programs:_Program.__init__.__globals__", "aux": None, "children": []},
        {"node": "None", "aux": None, "children": ["*"]},  # malformed: None with a leaf
        {"node": "dict", "aux": {"list": ["b", "a"]}, "children": ["*", "*"]},
        {"node": "tuple", "aux": {"ref": "builtins:eval"}, "children": []},
        {"node": "tuple", "aux": {"const": "ctjax._programs:os"}, "children": []},
        {
            "node": "tuple",
            "aux": {"enum": "ctjax._status:Status", "member": "__class__"},
            "children": [],
        },
    ],
)
def test_a_skeleton_names_nothing_outside_its_vocabulary(data):
    leaves = [{"array": None}] * len(data["children"])
    with pytest.raises((ValueError, KeyError)):  # whatever the error, the file is a miss
        _static_data.read_skeleton({"tree": data, "leaves": leaves})


def _one_kept_program(kept):
    """A program kept in `kept`: its outputs, its file and the arguments it was run on."""
    camera, normals, depth = _frame()
    brdf = PAPER.build(jnp.array([0.25]))
    expected = [
        np.asarray(a) for a in _frame_columns(brdf, ColocatedLight(), camera, normals, depth)
    ]
    (path,) = kept.glob("*.program")
    return expected, path, (brdf, camera, normals, depth)


class _Planted:
    """A pickle that runs code when loaded: it creates the file `marker`."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return Path.touch, (self.marker,)


@pytest.mark.parametrize("damage", ["truncated", "payload", "header", "renamed", "pickle"])
def test_a_damaged_or_foreign_program_is_a_miss(kept, loads, tmp_path, damage):
    expected, path, arguments = _one_kept_program(kept)
    blob = path.read_bytes()
    marker = tmp_path / "pickle-ran"
    if damage == "truncated":
        path.write_bytes(blob[: len(blob) // 2])
    elif damage == "payload":  # a bit flipped in jax.export's bytes
        path.write_bytes(blob[:-100] + bytes([blob[-100] ^ 1]) + blob[-99:])
    elif damage == "header":
        path.write_bytes(blob.replace(b'"leaves"', b'"leafs"', 1))
    elif damage == "renamed":  # another key's program under this key's name
        other = _frame(8, 10)
        _frame_columns(arguments[0], ColocatedLight(), *other)
        (moved,) = set(kept.glob("*.program")) - {path}
        moved.replace(path)
    else:  # the old format, and what an attacker would plant in it
        path.write_bytes(pickle.dumps((b"", _Planted(marker))))
    again = _fresh_call(*arguments)
    assert not loads and not marker.exists()
    for a, b in zip(expected, again, strict=True):
        np.testing.assert_array_equal(b, a)
    _fresh_call(*arguments)  # exported again, in place of the damaged file
    assert len(loads) == 1


@pytest.mark.parametrize("writable", ["folder", "file", "owner"])
def test_a_cache_another_user_can_write_is_not_used(kept, loads, monkeypatch, writable):
    expected, path, arguments = _one_kept_program(kept)
    if writable == "folder":
        kept.chmod(0o777)
    elif writable == "file":
        path.chmod(0o666)
    else:  # the files belong to another user (as though this process were someone else's)
        uid = os.getuid()
        monkeypatch.setattr(os, "getuid", lambda: uid + 1)
    before = path.stat()
    with pytest.warns(RuntimeWarning, match="another user can write"):
        again = _fresh_call(*arguments)
    assert not loads
    for a, b in zip(expected, again, strict=True):
        np.testing.assert_array_equal(b, a)
    if writable == "file":  # the folder is this user's: the program is written anew, private
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
        _fresh_call(*arguments)
        assert len(loads) == 1
    else:  # neither read nor written, and warned about once per process
        assert path.stat().st_mtime_ns == before.st_mtime_ns
        assert sorted(p.suffix for p in kept.glob("*")) == [".executable", ".program"]
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            _fresh_call(*arguments)
        assert not loads


def test_the_cache_folders_and_files_are_the_users_alone(tmp_path, monkeypatch):
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.setattr(jax.config, "update", lambda *args: None)  # JAX's cache as it is
    folder = tmp_path / "shared" / "ctjax"
    try:
        assert _performance.enable_compilation_cache(folder) == folder
        camera, normals, depth = _frame()
        _frame_columns(PAPER.build(jnp.array([0.25])), ColocatedLight(), camera, normals, depth)
    finally:
        _programs.keep_programs(None)
    (path,) = (folder / "programs").glob("*.program")
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    assert stat.S_IMODE((folder / "programs").stat().st_mode) == 0o700
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    group = tmp_path / "group"
    group.mkdir(mode=0o770)
    group.chmod(0o770)
    monkeypatch.setattr(_private_files, "_WARNED", [False])
    with pytest.warns(RuntimeWarning, match="another user can write"):
        assert _performance.enable_compilation_cache(group) is None
    assert _programs._FOLDER[0] is None


def test_ctjax_does_not_use_pickle():
    root = Path(ctjax.__file__).parent
    uses = re.compile(r"^\s*(import|from)\s+(c?pickle|dill|cloudpickle|shelve)\b|\bpickle\.")
    found = [
        f"{path.relative_to(root)}:{number}"
        for path in sorted(root.rglob("*.py"))
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if uses.search(line)
    ]
    assert not found


def _doubled(x):
    return 2 * x


def test_fitters_compile_with_the_loop_emitters_and_nest(kept):
    """A kept program is compiled with `compiler_options()` (XLA:CPU's loop emitters, which
    compile fitters faster); called inside another program it is part of that one (`jax.jit`
    refuses compiler options on a nested call), kept or not."""
    assert _programs.compiler_options() == {"xla_cpu_use_fusion_emitters": False}
    doubled = _programs.persistent_jit(_doubled)
    x = jnp.arange(3.0)
    np.testing.assert_array_equal(doubled(x), 2 * x)
    np.testing.assert_array_equal(jax.jit(lambda y: doubled(y) + 1)(x), 2 * x + 1)
    _programs.keep_programs(None)
    np.testing.assert_array_equal(jax.jit(lambda y: doubled(y) + 1)(x), 2 * x + 1)


def _tripled(x):
    return 3 * x


@pytest.mark.parametrize("keep", [True, False])
def test_a_function_compiles_with_its_own_options(kept, monkeypatch, keep):
    """`PROGRAM_OPTIONS` reaches the compiler for the function it names, kept or not (an
    option XLA does not know is refused there), and no other function."""
    if not keep:
        _programs.keep_programs(None)
    name = f"{__name__}._tripled"
    monkeypatch.setitem(_programs.PROGRAM_OPTIONS, name, {"xla_no_such_option": 1})
    assert _programs.options_for(name)["xla_no_such_option"] == 1
    assert _programs.options_for(f"{__name__}._doubled") == _programs.compiler_options()
    with pytest.raises(Exception, match="xla_no_such_option"):
        _programs.persistent_jit(_tripled)(jnp.arange(3.0))
    np.testing.assert_array_equal(_programs.persistent_jit(_doubled)(jnp.arange(3.0)), [0, 2, 4])


def test_programs_are_kept_beside_a_cache_set_through_jax(tmp_path):
    """With JAX's own `JAX_COMPILATION_CACHE_DIR`, the command line keeps the traced programs
    in its `programs/`, unless another user can write that folder."""
    script = (
        "from ctjax import _performance, _programs; "
        "_performance.enable_compilation_cache(); print(_programs._FOLDER[0])"
    )
    private, group = tmp_path / "private", tmp_path / "group"
    private.mkdir(mode=0o700)
    group.mkdir()
    group.chmod(0o770)
    printed = {}
    for folder in (private, group):
        env = {**os.environ, "JAX_COMPILATION_CACHE_DIR": str(folder)}
        env.pop("CTJAX_NO_CACHE", None)
        result = subprocess.run(
            [sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120
        )
        assert result.returncode == 0, result.stderr
        printed[folder] = result
    assert printed[private].stdout.strip() == str(private / "programs")
    assert printed[group].stdout.strip() == "None"
    assert "another user can write" in printed[group].stderr


# Run twice in new processes: "first" traces and keeps both programs, "again" loads them.
_LAPACK_SCRIPT = """
import json
import sys
import threading
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)
from ctjax import _programs  # noqa: E402
from ctjax._camera import Camera  # noqa: E402
from ctjax.estimation import PAPER  # noqa: E402
from ctjax.estimation._dense_maps import _frame_columns  # noqa: E402
from ctjax.lights import ColocatedLight  # noqa: E402

_programs.keep_programs(Path(sys.argv[1]))
again = sys.argv[2] == "again"


def stub(*args, **kwargs):
    raise AssertionError("a kept program was traced again")


def named(function, qualname):  # kept under a name of ctjax's (the key's)
    function.__module__, function.__qualname__ = _frame_columns.__module__, qualname
    return _programs.persistent_jit(function)


columns = named(stub if again else _frame_columns.__wrapped__, "_frame_columns")
solve = named(stub if again else lambda a, b: jnp.linalg.solve(a, b), "_lapack_probe")
camera = Camera(fx=20.0, fy=20.0, cx=8.0, cy=6.0, width=16, height=12)
normals = jnp.broadcast_to(jnp.array([0.0, 0.6, -0.8]), (12, 16, 3))
depth = jnp.full((12, 16), 60.0)
report = {"before": "scipy.linalg" in sys.modules}
out = columns(PAPER.build(jnp.array([0.25])), ColocatedLight(), camera, normals, depth)
report["columns"] = float(sum(np.nansum(np.asarray(o)) for o in out))
report["after_columns"] = "scipy.linalg" in sys.modules
a = np.array([[2.0, 0.5, 0.0], [0.5, 3.0, 0.1], [0.0, 0.1, 1.0]])
report["x"] = np.asarray(solve(jnp.asarray(a), jnp.arange(3.0))).tolist()
report["after_solve"] = "scipy.linalg" in sys.modules
print(json.dumps(report))
"""


@pytest.mark.slow
def test_lapack_is_set_up_only_for_programs_that_call_it(tmp_path):
    """A kept program without LAPACK kernels runs in a new process without JAX's LAPACK
    set-up (which imports scipy.linalg: `ctjax._lapack`); one that calls LAPACK, kept and
    loaded alike, still gets it and gives the right answer (lowered again: its executable
    is not kept)."""
    script = tmp_path / "probe.py"
    script.write_text(_LAPACK_SCRIPT)
    reports = []
    for run in ("first", "again"):
        done = subprocess.run(
            [sys.executable, str(script), str(tmp_path / "programs"), run],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert done.returncode == 0, done.stderr[-2000:]
        reports.append(json.loads(done.stdout.splitlines()[-1]))
    headers = [
        json.loads(path.read_bytes().split(b"\n", 2)[1])
        for path in (tmp_path / "programs").glob("*.program")
    ]
    assert sorted(h["lapack"] for h in headers) == [False, True]
    # Its executable kept for the program without LAPACK only (`ctjax._executables`).
    kept_executables = {p.stem for p in (tmp_path / "programs").glob("*.executable")}
    assert kept_executables == {h["key"] for h in headers if not h["lapack"]}
    a = np.array([[2.0, 0.5, 0.0], [0.5, 3.0, 0.1], [0.0, 0.1, 1.0]])
    for report in reports:
        assert not report["before"] and not report["after_columns"] and report["after_solve"]
        np.testing.assert_allclose(report["x"], np.linalg.solve(a, np.arange(3.0)), rtol=1e-12)
    assert reports[1]["columns"] == reports[0]["columns"] != 0


def test_threads_asking_for_one_program_at_once_export_it_once(kept, monkeypatch):
    """Two threads calling a kept function with the same shapes before either has loaded
    it: one exports it, the other waits for it (not each its own trace and compilation)."""
    import threading

    camera, normals, depth = _frame()
    brdf = PAPER.build(jnp.array([0.25]))
    exports, both_in = [], threading.Barrier(2)
    original = _programs._export

    def counted(*args):
        exports.append(threading.current_thread().name)
        return original(*args)

    monkeypatch.setattr(_programs, "_export", counted)
    fresh = _programs.persistent_jit(_frame_columns.__wrapped__)
    results = [None, None]

    def call(index):
        both_in.wait(5)
        results[index] = fresh(brdf, ColocatedLight(), camera, normals, depth)

    threads = [threading.Thread(target=call, args=(i,)) for i in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(60)
    assert len(exports) == 1 and len(list(kept.glob("*.program"))) == 1
    for a, b in zip(*results, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_whether_a_program_calls_the_linear_algebra_kernels_is_read_from_its_bytes_first():
    """`exported_calls_lapack`: a module without the kernels' prefix is not printed; one
    whose source locations hold it (a file or function named so) is printed and does not
    count; a Cholesky solve does."""
    from ctjax._lapack import exported_calls_lapack

    x = jax.ShapeDtypeStruct((3, 3), jnp.float64)

    def lapack_named(a):  # the prefix in its own name: the module's locations hold it
        return jnp.sin(a) @ a

    def plain(a):
        return jnp.cos(a) * 2

    def cholesky(a):
        return jnp.linalg.cholesky(a @ a.T + jnp.eye(3))

    exported = {f: jax.export.export(jax.jit(f))(x) for f in (lapack_named, plain, cholesky)}
    assert b"lapack_" in exported[lapack_named].mlir_module_serialized
    assert not exported_calls_lapack(exported[lapack_named])
    assert exported_calls_lapack(exported[cholesky])

    class Unprinted:  # the plain module's bytes alone: printing it would fail
        mlir_module_serialized = exported[plain].mlir_module_serialized

        def mlir_module(self):
            raise AssertionError("printed a module whose bytes hold no LAPACK prefix")

    assert not exported_calls_lapack(Unprinted())


def _arguments():
    camera, normals, depth = _frame()
    return PAPER.build(jnp.array([0.25])), ColocatedLight(), camera, normals, depth


def _no_lowering(monkeypatch):
    """From here on, a kept program that is lowered and compiled fails the test."""

    def compile(self, leaves):
        raise AssertionError("a kept program was lowered again")

    monkeypatch.setattr(_programs._Program, "compile", compile)


def test_a_kept_program_runs_from_its_executable_without_lowering(kept, monkeypatch):
    """`ctjax._executables`: beside the exported program, XLA's executable is kept; a new
    process (a fresh wrapper) runs it on the arguments' buffers, nothing traced, lowered or
    compiled, with the same result, bit for bit."""
    arguments = _arguments()
    first = [np.asarray(a) for a in _frame_columns(*arguments)]
    (path,) = kept.glob("*.program")
    executable = path.with_suffix(".executable")
    magic, header, _ = executable.read_bytes().split(b"\n", 2)
    header = json.loads(header)
    assert magic == b"ctjax-executable 1" and header["key"] == path.stem
    assert header["inputs"][-1] == [[12, 16], "float64"]  # the depth, as the file says
    assert stat.S_IMODE(executable.stat().st_mode) == 0o600
    _no_lowering(monkeypatch)
    reloaded = _programs.persistent_jit(_renamed_stub(_frame_columns.__wrapped__))
    again = [np.asarray(a) for a in reloaded(*arguments)]
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(b, a)


def test_an_executable_jax_read_from_its_cache_is_kept_whole(kept, monkeypatch):
    """The bytes kept are XLA's as JAX read them from its compilation cache, not the
    executable serialised again (which loses its kernels and fails when run: "Function
    ... not found"): the program compiled, its executable file removed, JAX's in-memory
    caches cleared; the next process compiles from JAX's cache and keeps the executable,
    the one after runs it."""
    from jax._src import compilation_cache

    arguments = _arguments()
    first = [np.asarray(a) for a in _frame_columns(*arguments)]
    (path,) = kept.glob("*.program")
    path.with_suffix(".executable").unlink()
    from jax._src.interpreters import pxla

    pxla.clear_in_memory_compilation_cache()  # the next compilation reads JAX's cache
    read = []
    extract = compilation_cache.extract_executable_and_time
    monkeypatch.setattr(  # the wrapper `ctjax._executables` installed, counted
        compilation_cache, "extract_executable_and_time", lambda b: read.append(1) or extract(b)
    )
    _fresh_call(*arguments[:1], *arguments[2:])
    assert read and path.with_suffix(".executable").exists()
    _no_lowering(monkeypatch)
    again = _fresh_call(*arguments[:1], *arguments[2:])
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(b, a)


@pytest.mark.parametrize(
    "damage", ["payload", "renamed", "platform", "flags", "options", "arguments"]
)
def test_an_executable_that_is_not_this_programs_is_compiled_again(kept, damage):
    """A damaged executable (refused before XLA reads it), another key's, another
    processor's, one compiled with other XLA flags or compiler options, or one for other
    arguments: the program is compiled again, gives the same result, and its executable is
    written anew."""
    arguments = _arguments()
    first = [np.asarray(a) for a in _frame_columns(*arguments)]
    (path,) = kept.glob("*.program")
    executable = path.with_suffix(".executable")
    blob = executable.read_bytes()
    magic, header, code = blob.split(b"\n", 2)
    data = json.loads(header)
    if damage == "payload":
        code = code[:-100] + bytes([code[-100] ^ 1]) + code[-99:]
    elif damage == "renamed":
        data["key"] = "0" * 64
    elif damage == "platform":
        data["cpu"] = "another processor"
    elif damage == "flags":
        data["xla_flags"] += " --xla_cpu_enable_fast_math=true"
    elif damage == "options":
        data["options"] = json.dumps({"xla_backend_optimization_level": 0})
    else:
        data["inputs"][-1] = [[8, 10], "float64"]
    planted = magic + b"\n" + json.dumps(data).encode() + b"\n" + code
    executable.write_bytes(planted)
    again = _fresh_call(*arguments[:1], *arguments[2:])
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(b, a)
    assert executable.read_bytes() != planted


def test_the_executables_a_command_used_are_loaded_ahead_when_it_is_repeated(kept, monkeypatch):
    """`loading_ahead`: a command's run writes down the programs it used (`<command>.recent`,
    with a digest of its words); the next run of the same words deserialises their
    executables on a thread before it asks for them, and runs them. Other words, another
    command or keys that are not programs' load nothing ahead."""
    from ctjax import _executables

    arguments = _arguments()
    words = ["probe", "capture", "--json", "out.json"]
    with _programs.loading_ahead("probe", words):
        first = [np.asarray(a) for a in _frame_columns(*arguments)]
    (path,) = kept.glob("*.program")
    recent = json.loads((kept / "probe.recent").read_bytes())
    assert recent["keys"] == [path.stem]
    recent["keys"] += ["../../etc/passwd", 3, "f" * 64]  # only the program's is loaded
    (kept / "probe.recent").write_text(json.dumps(recent))
    threads = []
    deserialised = _executables._deserialised
    monkeypatch.setattr(
        _executables,
        "_deserialised",
        lambda code: threads.append(threading.current_thread().name) or deserialised(code),
    )
    _no_lowering(monkeypatch)
    with _programs.loading_ahead("probe", words):
        again = _fresh_call(*arguments[:1], *arguments[2:])
    assert threads == ["ctjax-load-ahead"] and not _executables._AHEAD
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(b, a)
    for command, said in (("probe", [*words[:-1], "other.json"]), ("other", words)):
        with _programs.loading_ahead(command, said):
            assert not _executables._AHEAD
