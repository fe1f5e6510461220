"""Programs kept between processes: traced and lowered once, not in every command.

JAX's persistent compilation cache (`ctjax._performance.enable_compilation_cache`) saves
XLA's compilation, but its key is the lowered program: every process still traces and
lowers every fitter before it can look the program up, and for ctjax's fitters that is
most of a repeated command (a warm `ctjax diagnose` on 320x256 x 8 frames: about 17 s of
23). `persistent_jit` is `eqx.filter_jit` that also keeps the traced program, exported
(`jax.export`), in `programs/` beside the compilation cache: a later process with the same
code, the same static arguments and the same argument shapes loads it and only runs it.

The key is everything tracing depends on: the function, a digest of ctjax's source and
the versions of JAX and its libraries, the precision (`jax_enable_x64`), the platform,
the static part of the arguments (`repr` of everything `eqx.filter_jit` treats as static)
and the shape and dtype of every array. A static argument whose `repr` is not
reproducible (one showing an address) only makes the program miss the cache. A program
that cannot be exported (a host callback) runs as `eqx.filter_jit` would. Off unless the
compilation cache is on (the command line turns it on; `CTJAX_NO_CACHE=1` turns it off).

A kept program is data only, never pickled: whoever can write a file that a process
unpickles runs code in it. `<sha256 of the key>.program` holds the line
`ctjax-program 2` (the format and its version), one line of JSON, then the bytes of
`jax.export`'s `Exported.serialize()`. The JSON holds the key's digest (a file renamed to
another key is refused), the sha256 of those bytes (a damaged file is refused before
JAX parses it), whether the program calls LAPACK (JAX sets LAPACK up only for those:
`ctjax._lapack`) and the output's skeleton in a closed vocabulary (`ctjax._static_data`,
which also writes the key's static part). An output holding anything else (user code,
an object shown by address) is used in this process but not kept: it runs from the
exported program here, and a later process traces it again. A folder or a file that
another user can write is neither read nor written (`ctjax._private_files`). A file that
cannot be read, parsed or checked (damaged, another format, another key's) is a miss: the
function is traced again and the file replaced.

What the program compiled to is kept beside it too (`<key>.executable`,
`ctjax._executables`): a later process runs XLA's executable, nothing lowered, hashed or
compiled, and a repeated command loads ahead, on a thread, those its last run used
(`loading_ahead`).
"""

import contextlib
import functools
import hashlib
import importlib.metadata
import threading
from pathlib import Path

import equinox as eqx
import jax

from ctjax._executables import (
    Executable,
    executable_blob,
    keepable,
    loaded_ahead,
    read_executable,
    recorded,
    remember,
)
from ctjax._lapack import exported_calls_lapack, no_lapack_setup
from ctjax._private_files import (
    keyed_blob,
    private_folder,
    read_keyed,
    read_private,
    write_private,
)
from ctjax._static_data import (
    PACKAGES,
    Array,
    Unkeyable,
    keyed,
    read_skeleton,
    skeleton_data,
    structure,
)

# Where programs are kept; None: off (see `keep_programs`).
_FOLDER: list[Path | None] = [None]


def keep_programs(folder: Path | None) -> None:
    """Keep exported programs in `folder` (None: off)."""
    _FOLDER[0] = folder


_USED: list[str] = []  # the keys of the kept programs loaded in this process, in order


@contextlib.contextmanager
def loading_ahead(command: str, words: list[str]):
    """Run a command (`ctjax fit`, ...; `words`: its command line) with the executables its
    last run with the same words used loaded ahead on a thread
    (`ctjax._executables.loaded_ahead`), and write down the ones this run used."""
    folder = _FOLDER[0]
    if folder is None or not private_folder(folder):
        yield
        return
    start = len(_USED)
    try:
        with loaded_ahead(folder, command, words):
            yield
    finally:
        remember(folder, command, words, _USED[start:])


# XLA:CPU's loop emitters for the fitters (compiled once per model, run for milliseconds):
# they compile faster and run no slower. A cold `diagnose` (128x96 x 5, 108 programs):
# 52-62 s -> 38-44 s, compiling 41-49 s -> 27-30 s (alternating, two each); the renderer
# keeps the fusion emitters (4-7x faster there); the tests use loop emitters everywhere.
FITTER_COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False}


# XLA options for single functions, by qualified name ("ctjax.fitting._fit._least_squares"),
# over `compiler_options()`: for a setting that compiles most programs for the speed of
# compiling and a few long-running ones for the speed of running them (the test session,
# tests/conftest.py). Read when a function is first compiled in a process. Empty: none.
PROGRAM_OPTIONS: dict[str, dict] = {}


@functools.cache
def compiler_options() -> dict:
    """`jax.jit`'s `compiler_options` for a fitter on the default backend (XLA:CPU's loop
    emitters, `FITTER_COMPILER_OPTIONS`; none elsewhere). Asks for the backend: call it
    when compiling, not at import."""
    return dict(FITTER_COMPILER_OPTIONS) if jax.default_backend() == "cpu" else {}


def options_for(name: str) -> dict:
    """The compiler options of the function `name` (module.qualname): `compiler_options()`
    and its own `PROGRAM_OPTIONS`."""
    return {**compiler_options(), **PROGRAM_OPTIONS.get(name, {})}


def _qualified(fun) -> str:
    return f"{fun.__module__}.{fun.__qualname__}"


def _traced(args, kwargs) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves((args, kwargs)))


def fitter_jit(fun):
    """`eqx.filter_jit(fun)` compiled with `compiler_options()` (XLA:CPU's loop emitters):
    for programs compiled once and run briefly (fitters, linearisations), not for the
    renderer. Called inside another program's trace it is part of that program (`jax.jit`
    takes compiler options only at the top level)."""
    nested = eqx.filter_jit(fun)

    @functools.cache
    def top_level():  # at the first call: the backend is not known at import
        return eqx.filter_jit(fun, compiler_options=options_for(_qualified(fun)))

    @functools.wraps(fun)
    def call(*args, **kwargs):
        return (nested if _traced(args, kwargs) else top_level())(*args, **kwargs)

    return call


@functools.cache
def _code_digest() -> str:
    """ctjax's source and the versions of the libraries that shape a traced program."""
    digest = hashlib.sha256()
    root = Path(__file__).parent
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    for package in PACKAGES:
        try:
            digest.update(f"{package}={importlib.metadata.version(package)}".encode())
        except importlib.metadata.PackageNotFoundError:
            digest.update(package.encode())
    return digest.hexdigest()


def _aval(leaf) -> str:
    return f"{leaf.shape}{leaf.dtype}{getattr(leaf, 'weak_type', False)}"


class _Program:
    """One exported program: call it on the dynamic leaves, rebuild the output tree. It
    runs from its kept executable where there is one (`ctjax._executables`), else as JAX
    lowers and compiles the exported call. `exported` is a `jax.export.Exported` or its
    bytes, read when first needed (not where the kept executable runs)."""

    def __init__(self, exported, skeleton, options: dict, lapack: bool):
        self._exported = exported
        self.skeleton = skeleton
        self.options = options
        self.lapack = lapack  # whether it calls LAPACK (`ctjax._lapack`)
        self.parts, self.structure = jax.tree.flatten(skeleton)
        self.outputs = sum(isinstance(part, Array) for part in self.parts)
        self.compiled = None  # JAX's compiled program (`compile`)
        self.executable: Executable | None = None  # or the kept one, read back

    @functools.cached_property
    def exported(self) -> jax.export.Exported:
        if isinstance(self._exported, bytes | bytearray):
            return jax.export.deserialize(bytearray(self._exported))
        return self._exported

    def check(self, leaves) -> None:
        """Raise where the exported program is not one for arguments like `leaves`."""
        inputs = [(aval.shape, aval.dtype) for aval in self.exported.in_avals]
        if inputs != [(leaf.shape, leaf.dtype) for leaf in leaves]:
            raise ValueError("a program for other arguments")
        if len(self.exported.out_avals) != self.outputs:
            raise ValueError("a program for another output")

    def compile(self, leaves) -> bytes | None:
        """Lower and compile the exported call for `leaves` (JAX's compilation cache); the
        executable's bytes as XLA serialised them (None where not known: `recorded`)."""
        exported = self.exported

        def run(*leaves):
            return exported.call(*leaves)

        # Named as the function kept (`jax_log_compiles`, profiles): not "<lambda>".
        run.__name__ = run.__qualname__ = _plain_name(exported.fun_name)
        # Its inputs placed on the default device: committed and uncommitted arguments (an
        # exported program's outputs are committed) would otherwise compile it twice. Every
        # argument kept (`keep_unused`): the kept executable takes the leaves as they come.
        device = jax.sharding.SingleDeviceSharding(jax.devices()[0])
        jitted = jax.jit(run, in_shardings=device, keep_unused=True, compiler_options=self.options)
        with contextlib.nullcontext() if self.lapack else no_lapack_setup(), recorded() as code:
            self.compiled = jitted.lower(*leaves).compile()
        return code[0] if len(code) == 1 else None

    def __call__(self, leaves):
        if self.executable is not None:
            outputs = iter(self.executable(leaves))
        else:
            if self.compiled is None:
                self.compile(leaves)
            outputs = iter(self.compiled(*leaves))
        return jax.tree.unflatten(
            self.structure, [next(outputs) if isinstance(p, Array) else p for p in self.parts]
        )


def _export(fun, treedef, static, leaves):
    skeleton = []

    def flat(*dynamic):
        args, kwargs = eqx.combine(jax.tree.unflatten(treedef, dynamic), static)
        out_dynamic, out_static = eqx.partition(fun(*args, **kwargs), eqx.is_array)
        skeleton.append(eqx.combine(jax.tree.map(lambda _: Array(), out_dynamic), out_static))
        return jax.tree.leaves(out_dynamic)

    shapes = [
        jax.ShapeDtypeStruct(leaf.shape, leaf.dtype, weak_type=getattr(leaf, "weak_type", False))
        for leaf in leaves
    ]
    flat.__name__ = flat.__qualname__ = _plain_name(getattr(fun, "__name__", "program"))
    exported = jax.export.export(jax.jit(flat))(*shapes)
    lapack = exported_calls_lapack(exported)
    return _Program(exported, skeleton[0], options_for(_qualified(fun)), lapack)


def _plain_name(name) -> str:
    """A function name for a kept program: JAX's `jit(NAME)` in logs and profiles (a
    file's name, read back, is only ever used so)."""
    name = str(name).removeprefix("jit(").removesuffix(")")
    return "".join(c if c.isalnum() or c == "_" else "_" for c in name)[:80] or "program"


def persistent_jit(fun):
    """`eqx.filter_jit(fun)` whose traced program is also kept between processes (see the
    module doc). For module-level functions of their arguments only. Compiled with
    `compiler_options()` (XLA:CPU's loop emitters)."""
    loaded: dict[Path, _Program | None] = {}
    locks: dict[Path, threading.Lock] = {}  # threads asking for one program load it once
    name = _qualified(fun)

    jitted = fitter_jit(fun)

    @functools.wraps(fun)
    def call(*args, **kwargs):
        folder = _FOLDER[0]
        if folder is None or _traced(args, kwargs):  # traced: part of the caller's program
            return jitted(*args, **kwargs)
        dynamic, static = eqx.partition((args, kwargs), eqx.is_array)
        leaves, treedef = jax.tree.flatten(dynamic)
        try:
            text = "\n".join(
                [
                    name,
                    _code_digest(),
                    str(jax.config.jax_enable_x64),
                    jax.default_backend(),
                    structure(treedef),
                    keyed(jax.tree.leaves(static)),
                    ",".join(_aval(leaf) for leaf in leaves),
                ]
            )
        except Unkeyable:
            return jitted(*args, **kwargs)
        key = hashlib.sha256(text.encode()).hexdigest()
        path = folder / f"{key}.program"
        if path not in loaded:
            with locks.setdefault(path, threading.Lock()):
                if path not in loaded:
                    loaded[path] = _load(path, key, leaves, options_for(name)) or _save(
                        path, key, fun, treedef, static, leaves
                    )
                    _USED.append(key)
        program = loaded[path]
        return jitted(*args, **kwargs) if program is None else program(leaves)

    return call


_MAGIC = b"ctjax-program 2\n"  # the format and its version


def _blob(key: str, program: _Program) -> bytes:
    """A program file's bytes (see the module doc); raises `Unkeyable` for an output the
    format does not describe."""
    header = {"skeleton": skeleton_data(program.skeleton), "lapack": program.lapack}
    return keyed_blob(_MAGIC, key, header, bytes(program.exported.serialize()))


def _program(blob: bytes, key: str, options: dict) -> _Program:
    """The program a file's bytes hold; raises (anything) where they are not this key's."""
    header, exported = read_keyed(blob, _MAGIC, key)
    if type(header["lapack"]) is not bool:
        raise ValueError("not a program of this format")
    return _Program(exported, read_skeleton(header["skeleton"]), options, header["lapack"])


def _load(path: Path, key: str, leaves, options: dict) -> _Program | None:
    """The program kept for `key`, ready to run; None where there is none to use (a miss)."""
    if not private_folder(path.parent):
        return None
    try:
        blob = read_private(path)
        if blob is None:
            return None
        program = _program(blob, key, options)
        program.executable = _kept_executable(path, key, program, leaves)
        if program.executable is not None:
            return program
        program.check(leaves)
    except Exception:
        return None  # unreadable, damaged, another format or another key's: a miss
    return _compiled(program, path, key, leaves)


def _kept_executable(path: Path, key: str, program: _Program, leaves) -> Executable | None:
    """The executable kept beside the program at `path` (`ctjax._executables`); None where
    there is none to use: missing, unreadable, damaged, another platform's, or not for
    `leaves` (the program is then compiled, and the file replaced)."""
    try:
        path = path.with_suffix(".executable")
        return read_executable(path, key, leaves, program.outputs, program.options)
    except Exception:
        return None


def _compiled(program: _Program, path: Path, key: str, leaves, keep: bool = True) -> _Program:
    """`program` (kept at `path`) lowered and compiled by JAX for `leaves`, and its
    executable kept beside it where it can be (`keep`: the folder is the user's alone)."""
    code = program.compile(leaves)
    try:
        if keep and code and keepable(program.compiled, program.exported):
            in_avals = program.exported.in_avals
            blob = executable_blob(key, code, program.compiled, in_avals, program.options)
            write_private(path.with_suffix(".executable"), blob)
    except Exception:
        pass  # not kept: it runs as JAX compiled it
    return program


def _save(path: Path, key: str, fun, treedef, static, leaves) -> _Program | None:
    try:
        program = _export(fun, treedef, static, leaves)
    except Exception:
        return None
    try:
        blob = _blob(key, program)
    except Exception:
        return program  # an output the format does not describe: used here, not kept
    private = private_folder(path.parent)
    if private:
        write_private(path, blob)
    # Run as a later process will, from the bytes read back: a deserialised program
    # lowers to a module that differs from the freshly exported one (its operations in
    # another order), so the first process's compiled program would miss JAX's cache in
    # the second, which compiled every such program again (a second `ctjax fit` of a
    # 320x256 x 5 capture: 8.7 s, the third 2.9 s).
    try:
        read_back = _program(blob, key, options_for(_qualified(fun)))
        read_back.check(leaves)
    except Exception:
        return program
    return _compiled(read_back, path, key, leaves, keep=private)
