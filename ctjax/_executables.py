"""XLA's compiled code of the kept programs, kept beside them and run without lowering.

A kept program (`ctjax._programs`, `jax.export`'s bytes) spares a later process the
tracing, not the rest: calling it lowers the exported module into a jit of its own, hashes
that for JAX's compilation cache and reads the executable there. On a repeated `ctjax fit`
(320x256 x 5 frames, 7 programs) the lowering and the hashing took 0.13-0.2 s of the
command's 1.5 s. So the executable a program compiled to is kept too, in XLA's own
serialised form, as `<key>.executable` beside the program, and a later process
deserialises it and runs it on the arguments' buffers (`LoadedExecutable.execute_sharded`):
nothing lowered, nothing hashed.

The bytes kept are those XLA wrote when it compiled the program: serialised right after a
compilation in this process, or as JAX read them from its compilation cache (an executable
JAX read back from there serialises again without its kernels, and fails when run:
"Function ... not found"). `recorded()` notes them in the thread that compiles, from two
of JAX's internal functions (`compiler.backend_compile_and_load` and
`compilation_cache.extract_executable_and_time`); where JAX has neither (another version),
or the program came from JAX's in-memory cache, nothing is kept and the program runs as
JAX lowers it.

A file holds the line `ctjax-executable 1` (the format and its version), one line of JSON,
then the bytes. The JSON holds the key's digest (a file renamed to another key is refused),
the sha256 of the bytes (a damaged file is refused before XLA parses it), the platform, its
version, the host's processor (`_cpu`) and XLA's flags, the compiler options, and the
shape and dtype of every argument and output (checked against the program's). Compiled
code is code: whoever can write the file chooses what a later process runs, as with JAX's
compilation cache beside it, so it is read and written only where the kept programs are,
a folder of the user's alone (`ctjax._private_files`).

A repeated command loads ahead the executables its last run used (`loaded_ahead`): a run
writes down their keys (`<command>.recent`), and the next run of the same words
deserialises them on a thread while it reads its capture.

Only a program of one device, no effects, no custom call (jaxlib's LAPACK kernels, whose
addresses JAX sets up when it lowers: `ctjax._lapack`) and no weak-typed output (the
buffers XLA returns are not weak-typed) is kept so; the others run as JAX lowers them. A
file that cannot be read, parsed, checked or deserialised is a miss.
"""

import contextlib
import functools
import hashlib
import json
import os
import platform
import re
import threading
from concurrent.futures import Future
from pathlib import Path

import jax

from ctjax._private_files import keyed_blob, read_keyed, read_private, write_private

_MAGIC = b"ctjax-executable 1\n"  # the format and its version


_NOTES = threading.local()  # the list `recorded()` fills in this thread, if any
_INSTALLED = [False]


def _note(serialized) -> None:
    notes = getattr(_NOTES, "list", None)
    if notes is not None:
        notes.append(serialized())


def _install() -> bool:
    """Wrap JAX's compiling and cache reading to note the executables' bytes (module
    doc); False where JAX's internals differ."""
    if _INSTALLED[0]:
        return True
    try:
        from jax._src import compilation_cache, compiler

        extract = compilation_cache.extract_executable_and_time
        compile_and_load = compiler.backend_compile_and_load
    except (ImportError, AttributeError):  # another JAX: keep nothing
        return False

    def extract_executable_and_time(blob):
        serialized, compile_time = extract(blob)
        _note(lambda: bytes(serialized))
        return serialized, compile_time

    def backend_compile_and_load(backend, *args, **kwargs):
        executable = compile_and_load(backend, *args, **kwargs)
        _note(lambda: bytes(backend.serialize_executable(executable)))
        return executable

    compilation_cache.extract_executable_and_time = extract_executable_and_time
    compiler.backend_compile_and_load = backend_compile_and_load
    _INSTALLED[0] = True
    return True


@contextlib.contextmanager
def recorded():
    """A list that holds, after the block, the bytes of every executable compiled or read
    from JAX's compilation cache in it, in this thread (none where JAX's internals differ)."""
    notes: list[bytes] = []
    if not _install():
        yield notes
        return
    _NOTES.list = notes
    try:
        yield notes
    finally:
        _NOTES.list = None


@functools.cache
def _cpu() -> str:
    """The host's processor: its architecture and, on Linux, the digest of its feature
    flags (XLA compiles for the host's features; a cache shared by machines must not hand
    one's code to another)."""
    flags = ""
    with contextlib.suppress(OSError), open("/proc/cpuinfo") as info:
        flags = next((line for line in info if line.startswith(("flags", "Features"))), "")
    return f"{platform.machine()} {hashlib.sha256(flags.encode()).hexdigest()[:16]}"


def _platform() -> dict:
    """What an executable was compiled for besides its program: the platform, its version,
    the host's processor and XLA's flags (`XLA_FLAGS`, as `ctjax._performance.tune_xla`
    sets them)."""
    backend = jax.devices()[0].client
    return {
        "platform": backend.platform,
        "version": backend.platform_version,
        "cpu": _cpu(),
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
    }


def _options(options: dict) -> str:
    return json.dumps(options, sort_keys=True, default=str)


def _avals(avals) -> list:
    return [[list(aval.shape), str(aval.dtype)] for aval in avals]


class Executable:
    """A kept program's compiled code, loaded: called on the program's dynamic leaves (the
    arguments it was compiled for), it returns the output leaves."""

    def __init__(self, loaded, inputs: list):
        self.loaded = loaded  # XLA's `LoadedExecutable`
        self.inputs = inputs  # [[shape, dtype]] of every argument, as in the file
        self.device = jax.devices()[0]

    def __call__(self, leaves) -> list:
        arguments = jax.device_put(list(leaves), self.device)  # dtypes made JAX's (x64 off)
        if _avals(arguments) != self.inputs:
            raise ValueError("arguments other than those the program was compiled for")
        results = self.loaded.execute_sharded(arguments)
        return [shards[0] for shards in results.disassemble_into_single_device_arrays()]


def keepable(compiled, exported) -> bool:
    """Whether a program compiled by JAX (`jax.stages.Compiled` of `exported`, a
    `jax.export.Exported`) can be kept so (see the module doc): one device, no effects, no
    custom call (jaxlib's LAPACK kernels are the only ones ctjax's programs hold) and no
    weak-typed output."""
    module = bytes(exported.mlir_module_serialized)
    outputs = jax.tree.leaves(compiled.out_info)
    return (
        len(compiled.runtime_executable().local_devices()) == 1
        and not exported.ordered_effects
        and not exported.unordered_effects
        and b"custom_call" not in module  # MLIR's bytecode keeps the operation's name whole
        and not any(getattr(leaf, "weak_type", False) for leaf in outputs)
    )


def executable_blob(key: str, code: bytes, compiled, in_avals, options: dict) -> bytes:
    """The bytes of the file keeping `code`, XLA's serialised form of `compiled` (a
    `jax.stages.Compiled` of a program whose arguments are `in_avals`, every one kept:
    `keep_unused`; compiled with `options`, `jax.jit`'s `compiler_options`), as
    `recorded()` noted them."""
    if len(compiled.runtime_executable().get_parameter_layouts()) != len(in_avals):
        raise ValueError("an executable that does not take every argument")
    header = {
        **_platform(),
        "options": _options(options),
        "inputs": _avals(in_avals),
        "outputs": _avals(jax.tree.leaves(compiled.out_info)),
    }
    return keyed_blob(_MAGIC, key, header, code)


def _checked(blob: bytes, key: str) -> tuple[dict, bytes]:
    """A file's header and XLA's bytes; raises where they are not this key's, on this
    platform, or damaged (before XLA parses them)."""
    header, code = read_keyed(blob, _MAGIC, key)
    if {k: header.get(k) for k in _platform()} != _platform():
        raise ValueError("an executable for another platform")
    return header, code


def _deserialised(code: bytes):
    device = jax.devices()[0]
    return device.client.deserialize_executable(code, [device])


def read_executable(path: Path, key: str, leaves, outputs: int, options: dict) -> Executable | None:
    """The executable kept at `path` for `key` (loaded ahead where `loaded_ahead` did);
    None where there is none; raises (anything) where the file is not this key's, for
    arguments like `leaves` and `outputs` outputs, compiled with `options` on this
    platform."""
    ahead = _AHEAD.pop(key, None)
    blob, loaded = ahead.result() if ahead is not None else (read_private(path), None)
    if blob is None:
        return None
    header, code = _checked(blob, key)
    if header["inputs"] != _avals(leaves) or len(header["outputs"]) != outputs:
        raise ValueError("an executable for other arguments or outputs")
    if header["options"] != _options(options):
        raise ValueError("an executable compiled with other options")
    return Executable(loaded or _deserialised(code), header["inputs"])


# Loading ahead: a repeated command (the same words in the same folder) calls the same kept
# programs, the first of them after the capture is read and its tracks followed (a
# repeated `ctjax fit` of 320x256 x 5 frames: 0.6 s in, then 0.2-0.3 s deserialising its
# executables, most of it the branch and bound's). So a command's run writes down the
# keys it used (`<command>.recent` beside the programs, with a digest of its words), and
# the next run of the same words deserialises their executables on a thread while it reads
# its capture (XLA does not hold the GIL there). Other words load nothing ahead: a key the
# run does not ask for would cost the thread's time and the executable's memory.
_AHEAD: dict[str, Future] = {}  # key -> (the file's bytes, XLA's executable or None)
_KEY = re.compile(r"[0-9a-f]{64}")


def _recent(folder: Path, command: str) -> Path:
    return folder / f"{command}.recent"


def _words(words: list[str]) -> str:
    """A digest of a command's words and the folder they were said in."""
    return hashlib.sha256(json.dumps([os.getcwd(), list(words)]).encode()).hexdigest()


def _recent_keys(folder: Path, command: str, words: list[str]) -> list[str]:
    """The keys the last run of `command` used, where it had these `words`."""
    try:
        recent = json.loads(read_private(_recent(folder, command)) or b"{}")
        if recent.get("words") != _words(words):
            return []
        keys = recent["keys"]
    except (OSError, ValueError, KeyError, AttributeError):
        return []
    return [key for key in keys if isinstance(key, str) and _KEY.fullmatch(key)]


@contextlib.contextmanager
def loaded_ahead(folder: Path, command: str, words: list[str]):
    """In this block, deserialise on a thread the executables the last run of `command`
    used, where it had the same `words` (written down in `folder`, a folder of the user's
    alone); those not asked for by the block's end are let go then."""
    keys = _recent_keys(folder, command, words)
    futures = {key: Future() for key in dict.fromkeys(keys) if key not in _AHEAD}
    if not futures:
        yield
        return
    _AHEAD.update(futures)

    def load():
        for key, future in futures.items():
            loaded = None
            try:
                blob = read_private(folder / f"{key}.executable")
                if blob is not None:
                    loaded = _deserialised(_checked(blob, key)[1])
            except Exception:
                blob = None  # read again, and refused, where the key is asked for
            future.set_result((blob, loaded))

    thread = threading.Thread(target=load, name="ctjax-load-ahead", daemon=True)
    thread.start()
    try:
        yield
    finally:
        thread.join()  # not deserialising while the interpreter shuts down
        for key in futures:
            _AHEAD.pop(key, None)


def remember(folder: Path, command: str, words: list[str], keys: list[str]) -> None:
    """Write down the keys of the programs a run of `command` with `words` used, for
    `loaded_ahead`."""
    if keys:
        recent = {"words": _words(words), "keys": list(dict.fromkeys(keys))}
        write_private(_recent(folder, command), json.dumps(recent).encode())
