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
"""

import functools
import hashlib
import importlib.metadata
import os
import pickle
import types
from pathlib import Path

import equinox as eqx
import jax

_PACKAGES = ("jax", "jaxlib", "equinox", "optimistix", "lineax", "interpax", "numpy")
# Where programs are kept; None: off (see `keep_programs`).
_FOLDER: list[Path | None] = [None]


def keep_programs(folder: Path | None) -> None:
    """Keep exported programs in `folder` (None: off)."""
    _FOLDER[0] = folder


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

    def __init__(self, exported, skeleton):
        self.exported = exported
        self.skeleton = skeleton
        # One jit per program, its inputs placed on the default device: committed and
        # uncommitted arguments (an exported program's outputs are committed) would
        # otherwise compile the program twice.
        device = jax.sharding.SingleDeviceSharding(jax.devices()[0])
        self.run = jax.jit(lambda *leaves: exported.call(*leaves), in_shardings=device)

    def __call__(self, leaves):
        outputs = iter(self.run(*leaves))
        parts, structure = jax.tree.flatten(self.skeleton)
        return jax.tree.unflatten(
            structure, [next(outputs) if isinstance(p, _Array) else p for p in parts]
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
    exported = jax.export.export(jax.jit(flat))(*shapes)
    return _Program(exported, skeleton[0])


def persistent_jit(fun):
    """`eqx.filter_jit(fun)` whose traced program is also kept between processes (see the
    module doc). For module-level functions of their arguments only."""
    jitted = eqx.filter_jit(fun)
    loaded: dict[Path, _Program | None] = {}
    name = f"{fun.__module__}.{fun.__qualname__}"

    @functools.wraps(fun)
    def call(*args, **kwargs):
        folder = _FOLDER[0]
        if folder is None:
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
        path = folder / f"{hashlib.sha256(text.encode()).hexdigest()}.program"
        if path not in loaded:
            loaded[path] = _load(path) or _save(path, fun, treedef, static, leaves)
        program = loaded[path]
        return jitted(*args, **kwargs) if program is None else program(leaves)

    return call


def _load(path: Path) -> _Program | None:
    try:
        with path.open("rb") as file:
            blob, skeleton = pickle.load(file)
        return _Program(jax.export.deserialize(blob), skeleton)
    except FileNotFoundError:
        return None
    except Exception:
        return None


def _save(path: Path, fun, treedef, static, leaves) -> _Program | None:
    try:
        program = _export(fun, treedef, static, leaves)
        blob = pickle.dumps((program.exported.serialize(), program.skeleton))
    except Exception:
        return None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary = path.with_suffix(f".{os.getpid()}.tmp")
        temporary.write_bytes(blob)
        temporary.replace(path)  # atomic: concurrent processes never read half a file
    except OSError:
        pass  # a read-only cache: keep the program for this process only
    return program
