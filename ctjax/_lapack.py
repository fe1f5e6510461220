"""LAPACK set up only for the kept programs that call it.

JAX sets up its CPU LAPACK kernels the first time it lowers an operation that needs one
(`jax.lax.linalg`'s lowering rules), which imports `scipy.linalg` for their addresses:
0.15-0.3 s a process. An exported program (`jax.export`, what `ctjax._programs` keeps)
is opaque to JAX, so lowering a call to one sets LAPACK up whatever the program holds
(`jax._src.export._export._ensure_backends_initialized`), and every command that runs a
kept fitter paid for it, though none of `ctjax fit`'s programs calls LAPACK.

`ctjax._programs` records in each kept program whether its module names a LAPACK kernel
(`calls_lapack`) and lowers the others under `no_lapack_setup()`: the set-up is skipped
there and only there (a context variable, so other threads lower as JAX does), which is
JAX's own rule for the programs it traces. Where JAX's internals differ (another
version), nothing is changed and every exported call sets LAPACK up as before.
"""

import contextlib
import contextvars
import re

_SKIP = contextvars.ContextVar("ctjax_skip_lapack_setup", default=False)
_INSTALLED = [False]


# A custom call to one of jaxlib's LAPACK kernels, in StableHLO's pretty or generic form
# (not merely the word: the text carries the tracing's source locations too).
_LAPACK_CALL = re.compile(r'custom_call\s*@lapack_|call_target_name\s*=\s*"lapack_')


def calls_lapack(module_text: str) -> bool:
    """Whether a program's StableHLO text calls one of jaxlib's LAPACK kernels."""
    return _LAPACK_CALL.search(module_text) is not None


def exported_calls_lapack(exported) -> bool:
    """`calls_lapack` of an `Exported`'s module, printed as text only where its bytecode
    holds the kernels' prefix at all (MLIR's bytecode keeps strings whole: on 779 kept
    programs, 136 of them calling LAPACK, the bytes held it wherever the text's custom
    calls did). Printing a module takes 19 ms on average, most of an export's overhead."""
    if b"lapack_" not in bytes(exported.mlir_module_serialized):
        return False
    return calls_lapack(exported.mlir_module())


def _install() -> None:
    if _INSTALLED[0]:
        return
    _INSTALLED[0] = True
    try:
        from jax._src.export import _export
    except ImportError:  # another JAX: leave it as it is
        return
    original = getattr(_export, "_ensure_backends_initialized", None)
    if original is None:
        return

    def ensure_backends_initialized(platforms):
        if not _SKIP.get():
            original(platforms)

    _export._ensure_backends_initialized = ensure_backends_initialized


@contextlib.contextmanager
def no_lapack_setup():
    """Lower exported calls in this block without setting up LAPACK (their programs
    must not call it: `calls_lapack`)."""
    _install()
    token = _SKIP.set(True)
    try:
        yield
    finally:
        _SKIP.reset(token)
