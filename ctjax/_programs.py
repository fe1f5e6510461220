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
`ctjax._lapack`) and the output's skeleton, which only tracing would tell otherwise: the
pytree structure of the function's output (its node types, their static data) and its
leaves, each either "an output array of the program" or a static value. Static data is
written in a closed vocabulary: None, bool, int, float, str, tuples, lists and dicts of
those, classes of ctjax and its libraries (and ctjax's functions) by `module:qualname`,
enum members, and module-level constants of those libraries (equinox's MISSING). A name
is looked up in modules already imported, through `__dict__`s, and must be where the
object is defined: reading a program imports nothing, and the only code it runs is JSON's
parser, `jax.export.deserialize` and the named pytree types' own unflattening. A skeleton
is written only if it reads back the same. An output holding anything else (user code,
an object shown by address) is used in this process but not kept: it runs from the
exported program here, and a later process traces it again.

Safety rules. The cache folder, `programs/` and its files are created for the user alone
(0700, 0600). A folder that another user can write (owned by another user, or group- or
world-writable) is neither read nor written, and a program file that another user can
write is not read (it is replaced), with one warning per process: whoever can write a
kept program, or JAX's compiled programs beside it, chooses the machine code this process
runs (`enable_compilation_cache` leaves such a cache folder off altogether). Only the
folder and the file are checked: one that another user put in their place is theirs. A
file that cannot be read, parsed or checked (damaged, another format, another key's) is a
miss: the function is traced again and the file replaced.
"""

import contextlib
import enum
import functools
import hashlib
import importlib.metadata
import json
import os
import stat
import sys
import tempfile
import threading
import types
import warnings
from pathlib import Path

import equinox as eqx
import jax

from ctjax._lapack import exported_calls_lapack, no_lapack_setup

_PACKAGES = ("jax", "jaxlib", "equinox", "optimistix", "lineax", "interpax", "numpy")
# Where programs are kept; None: off (see `keep_programs`).
_FOLDER: list[Path | None] = [None]


def keep_programs(folder: Path | None) -> None:
    """Keep exported programs in `folder` (None: off)."""
    _FOLDER[0] = folder


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
    for package in _PACKAGES:
        try:
            digest.update(f"{package}={importlib.metadata.version(package)}".encode())
        except importlib.metadata.PackageNotFoundError:
            digest.update(package.encode())
    return digest.hexdigest()


class _Array:
    """Where an output array goes in the kept output structure."""


class _Unkeyable(Exception):
    """Static data another process may not reproduce (user code, an address)."""


# Code whose behaviour the key covers: ctjax's source (digest) and these libraries' versions.
_KNOWN = ("ctjax", "builtins", *_PACKAGES, "lineax", "jaxtyping", "numpy")
_PLAIN = (type(None), bool, int, float, complex, str, bytes)


def _known(thing) -> bool:
    return getattr(thing, "__module__", "").split(".")[0] in _KNOWN


def _keyed(value) -> str:
    """Static data as text that another process reproduces exactly; raises `_Unkeyable`
    for anything whose behaviour the key does not cover (code outside ctjax and its
    libraries, objects shown by address)."""
    if isinstance(value, _PLAIN):
        return repr(value)
    if isinstance(value, (tuple, list, frozenset)):
        return f"{type(value).__name__}({','.join(_keyed(v) for v in value)})"
    if isinstance(value, dict):
        return f"dict({','.join(f'{_keyed(k)}:{_keyed(v)}' for k, v in value.items())})"
    if isinstance(value, (types.FunctionType, type)):
        if _known(value) and "<" not in value.__qualname__:
            return f"{value.__module__}.{value.__qualname__}"
        raise _Unkeyable
    text = repr(value)
    if not _known(type(value)) or " at 0x" in text:
        raise _Unkeyable
    return f"{type(value).__module__}.{type(value).__qualname__}:{text}"


def _structure(treedef) -> str:
    """A pytree structure as text: node types, their static data, the leaves' places."""
    data = treedef.node_data()
    if data is None:
        return "*"
    kind, aux = data
    children = ",".join(_structure(child) for child in treedef.children())
    return f"{_keyed(kind)}[{_keyed(aux)}]({children})"


def _aval(leaf) -> str:
    return f"{leaf.shape}{leaf.dtype}{getattr(leaf, 'weak_type', False)}"


class _Program:
    """One exported program: call it on the dynamic leaves, rebuild the output tree."""

    def __init__(self, exported, skeleton, options: dict, lapack: bool):
        self.exported = exported
        self.skeleton = skeleton
        self.lapack = lapack  # whether it calls LAPACK (`ctjax._lapack`)
        self.parts, self.structure = jax.tree.flatten(skeleton)
        # One jit per program, its inputs placed on the default device: committed and
        # uncommitted arguments (an exported program's outputs are committed) would
        # otherwise compile the program twice.
        device = jax.sharding.SingleDeviceSharding(jax.devices()[0])

        def run(*leaves):
            return exported.call(*leaves)

        # Named as the function kept (`jax_log_compiles`, profiles): not "<lambda>".
        run.__name__ = run.__qualname__ = _plain_name(exported.fun_name)
        self.run = jax.jit(run, in_shardings=device, compiler_options=options)

    def __call__(self, leaves):
        with contextlib.nullcontext() if self.lapack else no_lapack_setup():
            outputs = iter(self.run(*leaves))
        return jax.tree.unflatten(
            self.structure, [next(outputs) if isinstance(p, _Array) else p for p in self.parts]
        )


def _export(fun, treedef, static, leaves):
    skeleton = []

    def flat(*dynamic):
        args, kwargs = eqx.combine(jax.tree.unflatten(treedef, dynamic), static)
        out_dynamic, out_static = eqx.partition(fun(*args, **kwargs), eqx.is_array)
        skeleton.append(eqx.combine(jax.tree.map(lambda _: _Array(), out_dynamic), out_static))
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
                    _structure(treedef),
                    _keyed(jax.tree.leaves(static)),
                    ",".join(_aval(leaf) for leaf in leaves),
                ]
            )
        except _Unkeyable:
            return jitted(*args, **kwargs)
        key = hashlib.sha256(text.encode()).hexdigest()
        path = folder / f"{key}.program"
        if path not in loaded:
            with locks.setdefault(path, threading.Lock()):
                if path not in loaded:
                    loaded[path] = _load(path, key, leaves, options_for(name)) or _save(
                        path, key, fun, treedef, static, leaves
                    )
        program = loaded[path]
        return jitted(*args, **kwargs) if program is None else program(leaves)

    return call


# The skeleton in JSON (see the module doc). Libraries whose classes and constants it may
# name: the key covers their versions, and naming one imports or runs nothing of theirs.
_LIBRARIES = ("ctjax", *_PACKAGES, "jaxtyping")
# The container node types, by name: the only builtins a skeleton names.
_CONTAINERS = {"tuple": tuple, "list": list, "dict": dict, "None": type(None)}


def _library(module: str) -> types.ModuleType:
    """An already imported module of ctjax or its libraries (importing one runs its code)."""
    if not isinstance(module, str) or module.split(".")[0] not in _LIBRARIES:
        raise ValueError(f"not a library of ctjax's: {module!r}")
    return sys.modules[module]


def _named(name: str):
    """The class of a library, or the function of ctjax's, that `module:qualname` names.
    Looked up in `__dict__`s, where no module `__getattr__` or descriptor runs, and only
    where it is defined: a name cannot reach an object imported into the module."""
    module, _, qualname = name.partition(":")
    thing = _library(module)
    for part in qualname.split("."):
        thing = vars(thing)[part]
    function = isinstance(thing, types.FunctionType) and module.split(".")[0] == "ctjax"
    if not (isinstance(thing, type) or function) or "<" in qualname:
        raise ValueError(f"not a class or a ctjax function: {name}")
    if (thing.__module__, thing.__qualname__) != (module, qualname):
        raise ValueError(f"not defined as {name}")
    return thing


def _name(thing) -> str:
    """`module:qualname` for `_named`; raises `_Unkeyable` where none finds `thing`."""
    name = f"{getattr(thing, '__module__', None)}:{getattr(thing, '__qualname__', None)}"
    try:
        if _named(name) is thing:
            return name
    except (KeyError, TypeError, ValueError):
        pass
    raise _Unkeyable


def _constant(name: str):
    """The module-level constant `module:name` (equinox's MISSING): data of a type that
    module defines, neither a class, a function nor anything else callable."""
    module, _, attribute = name.partition(":")
    value = vars(_library(module))[attribute]
    if type(value).__module__ != module or callable(value):
        raise ValueError(f"not a constant: {name}")
    return value


def _encoded(value):
    """Static data as JSON data (see the module doc); raises `_Unkeyable` for anything
    else."""
    if isinstance(value, enum.Enum):
        return {"enum": _name(type(value)), "member": value.name}
    if value is None or type(value) in (bool, int, float, str):
        return value
    if type(value) in (tuple, list):
        return {type(value).__name__: [_encoded(item) for item in value]}
    if type(value) is dict:
        return {"dict": [[_encoded(k), _encoded(v)] for k, v in value.items()]}
    if isinstance(value, (type, types.FunctionType)):
        return {"ref": _name(value)}
    module = type(value).__module__
    if module.split(".")[0] in _LIBRARIES and module in sys.modules:
        for attribute, bound in vars(sys.modules[module]).items():
            if bound is value and not callable(value):
                return {"const": f"{module}:{attribute}"}
    raise _Unkeyable


def _decoded(data):
    """The static data `_encoded` wrote; raises where `data` is not any."""
    if data is None or type(data) in (bool, int, float, str):
        return data
    if type(data) is not dict:
        raise ValueError(f"not static data: {data!r}")
    if data.keys() == {"enum", "member"}:
        kind = _named(data["enum"])
        if not issubclass(kind, enum.Enum):
            raise ValueError(f"not an enum: {kind}")
        return kind.__members__[data["member"]]
    ((tag, payload),) = data.items()
    if tag in ("tuple", "list", "dict") and type(payload) is not list:
        raise ValueError(f"not a {tag}: {payload!r}")
    if tag == "tuple":
        return tuple(_decoded(item) for item in payload)
    if tag == "list":
        return [_decoded(item) for item in payload]
    if tag == "dict":
        return {_decoded(k): _decoded(v) for k, v in payload}
    if tag == "ref":
        return _named(payload)
    if tag == "const":
        return _constant(payload)
    raise ValueError(f"not static data: {data!r}")


def _encoded_tree(treedef):
    """A pytree structure as JSON data: "*" for a leaf, else its node type, the node's
    static data and its children."""
    data = treedef.node_data()
    if data is None:
        return "*"
    kind, aux = data
    names = {kind: name for name, kind in _CONTAINERS.items()}
    return {
        "node": names[kind] if kind in names else _name(kind),
        "aux": _encoded(aux),
        "children": [_encoded_tree(child) for child in treedef.children()],
    }


def _decoded_tree(data):
    """The pytree structure `_encoded_tree` wrote; raises where `data` is not one."""
    registry = jax.tree_util.default_registry
    if data == "*":
        return jax.tree_util.PyTreeDef.from_node_data_and_children(registry, None, [])
    kind = _CONTAINERS[data["node"]] if data["node"] in _CONTAINERS else _named(data["node"])
    children = [_decoded_tree(child) for child in data["children"]]
    return jax.tree_util.PyTreeDef.from_node_data_and_children(
        registry, (kind, _decoded(data["aux"])), children
    )


def _skeleton(data):
    """The output skeleton `_skeleton_data` wrote; raises where `data` is not one."""
    treedef = _decoded_tree(data["tree"])
    parts = [_Array() if leaf == {"array": None} else _decoded(leaf) for leaf in data["leaves"]]
    skeleton = jax.tree.unflatten(treedef, parts)
    # Node types' unflattening accepts some malformed structures (a None with a child, a
    # dict's keys out of order): what does not flatten back to itself is not a skeleton.
    again, structure = jax.tree.flatten(skeleton)
    if structure != treedef or len(again) != len(parts):
        raise ValueError("not an output skeleton")
    if any(a is not b for a, b in zip(again, parts, strict=True)):
        raise ValueError("not an output skeleton")
    return skeleton


def _skeleton_data(skeleton) -> dict:
    """An output skeleton (`_Program`) as JSON data; raises `_Unkeyable` where it holds
    anything the format does not describe, or it does not read back the same."""
    parts, treedef = jax.tree.flatten(skeleton)
    data = {
        "tree": _encoded_tree(treedef),
        "leaves": [{"array": None} if isinstance(p, _Array) else _encoded(p) for p in parts],
    }
    # A kept program must rebuild exactly the output it was traced for: a name another
    # object answers to, or a type JSON does not tell apart, is caught here, not later.
    try:
        again, structure = jax.tree.flatten(_skeleton(json.loads(json.dumps(data))))
        same = structure == treedef and all(
            isinstance(a, _Array) == isinstance(b, _Array)
            and (isinstance(a, _Array) or (type(a) is type(b) and _keyed(a) == _keyed(b)))
            for a, b in zip(parts, again, strict=True)
        )
    except Exception as error:
        raise _Unkeyable from error
    if not same:
        raise _Unkeyable
    return data


_MAGIC = b"ctjax-program 2\n"  # the format and its version


def _blob(key: str, program: _Program) -> bytes:
    """A program file's bytes (see the module doc); raises `_Unkeyable` for an output the
    format does not describe."""
    exported = bytes(program.exported.serialize())
    header = {
        "key": key,
        "sha256": hashlib.sha256(exported).hexdigest(),
        "skeleton": _skeleton_data(program.skeleton),
        "lapack": program.lapack,
    }
    return _MAGIC + json.dumps(header, separators=(",", ":")).encode() + b"\n" + exported


def _program(blob: bytes, key: str, leaves, options: dict) -> _Program:
    """The program a file's bytes hold; raises (anything) where they are not this key's
    program for arguments like `leaves`."""
    if not blob.startswith(_MAGIC):
        raise ValueError("not a program of this format")
    line, _, exported = blob[len(_MAGIC) :].partition(b"\n")
    header = json.loads(line)
    if header["key"] != key or header["sha256"] != hashlib.sha256(exported).hexdigest():
        raise ValueError("another key's program, or a damaged one")
    if type(header["lapack"]) is not bool:
        raise ValueError("not a program of this format")
    exported = jax.export.deserialize(bytearray(exported))
    program = _Program(exported, _skeleton(header["skeleton"]), options, header["lapack"])
    inputs = [(aval.shape, aval.dtype) for aval in program.exported.in_avals]
    outputs = sum(isinstance(part, _Array) for part in program.parts)
    if inputs != [(leaf.shape, leaf.dtype) for leaf in leaves]:
        raise ValueError("a program for other arguments")
    if len(program.exported.out_avals) != outputs:
        raise ValueError("a program for another output")
    return program


_WARNED = [False]  # one warning per process for a cache others can write (module doc)


def _private(status: os.stat_result) -> bool:
    """Owned by this user, and writable by no other (neither group- nor world-writable)."""
    owner = not hasattr(os, "getuid") or status.st_uid == os.getuid()
    return owner and not status.st_mode & (stat.S_IWGRP | stat.S_IWOTH)


def _warn_unsafe(path: Path) -> None:
    if not _WARNED[0]:
        _WARNED[0] = True
        warnings.warn(
            f"ctjax: not using the cache at {path}: another user can write to it (it is not "
            "yours, or it is group- or world-writable), and whoever writes it chooses the "
            "code ctjax runs; make it yours alone (chmod go-w) or set CTJAX_CACHE_DIR to a "
            "folder of your own",
            RuntimeWarning,
            stacklevel=3,
        )


def private_folder(folder: Path) -> bool:
    """Whether `folder` is the user's alone, or missing (it is then created so); warns
    once per process otherwise (see the module doc)."""
    try:
        status = folder.stat()
    except FileNotFoundError:
        return True
    except OSError:
        return False
    if not _private(status):
        _warn_unsafe(folder)
        return False
    return True


def _read(path: Path) -> bytes | None:
    """A program file's bytes; None where it is missing, or another user can write it."""
    try:
        # Not through a link; not blocking on a FIFO (checked below: a regular file only).
        descriptor = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError:
        return None  # missing: the usual miss
    with os.fdopen(descriptor, "rb") as file:
        status = os.fstat(file.fileno())  # the file opened, not whatever the path is now
        if not stat.S_ISREG(status.st_mode):
            return None
        if not _private(status):
            _warn_unsafe(path)
            return None
        return file.read()


def _load(path: Path, key: str, leaves, options: dict) -> _Program | None:
    """The program kept for `key`; None where there is none to use (a miss)."""
    if not private_folder(path.parent):
        return None
    try:
        blob = _read(path)
        return None if blob is None else _program(blob, key, leaves, options)
    except Exception:
        return None  # unreadable, damaged, another format or another key's: a miss


def _save(path: Path, key: str, fun, treedef, static, leaves) -> _Program | None:
    try:
        program = _export(fun, treedef, static, leaves)
    except Exception:
        return None
    try:
        blob = _blob(key, program)
    except Exception:
        return program  # an output the format does not describe: used here, not kept
    if private_folder(path.parent):
        _write(path, blob)
    # Run as a later process will, from the bytes read back: a deserialised program
    # lowers to a module that differs from the freshly exported one (its operations in
    # another order), so the first process's compiled program would miss JAX's cache in
    # the second, which compiled every such program again (a second `ctjax fit` of a
    # 320x256 x 5 capture: 8.7 s, the third 2.9 s).
    try:
        return _program(blob, key, leaves, options_for(_qualified(fun)))
    except Exception:
        return program


def _write(path: Path, blob: bytes) -> None:
    try:
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        descriptor, temporary = tempfile.mkstemp(dir=path.parent, suffix=".tmp")  # 0600
    except OSError:
        return  # a read-only cache: keep the program for this process only
    try:
        with os.fdopen(descriptor, "wb") as file:
            file.write(blob)
        os.replace(temporary, path)  # atomic: concurrent processes never read half a file
    except OSError:
        Path(temporary).unlink(missing_ok=True)
