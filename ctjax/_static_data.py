"""Static data in a closed vocabulary: the text that keys a kept program, and the JSON
that describes its output (`ctjax._programs`).

`keyed` writes the static part of a program's arguments as text another process
reproduces exactly, and refuses (`Unkeyable`) anything whose behaviour the key does not
cover: code outside ctjax and its libraries, objects shown by their address.

`skeleton_data` writes a kept program's output skeleton, which only tracing would tell
otherwise, as JSON data: the pytree structure of the output (its node types, their static
data) and its leaves, each either "an output array of the program" (`Array`) or a static
value; `read_skeleton` reads it back. Static data is written in a closed vocabulary: None,
bool, int, float, str, tuples, lists and dicts of those, classes of ctjax and its
libraries (and ctjax's functions) by `module:qualname`, enum members, and module-level
constants of those libraries (equinox's MISSING). A name is looked up in modules already
imported, through `__dict__`s, and must be where the object is defined: reading a skeleton
imports nothing, and the only code it runs is JSON's parser and the named pytree types'
own unflattening. A skeleton is written only if it reads back the same.
"""

import enum
import json
import sys
import types

import jax

# The libraries that shape a traced program: the key covers their versions.
PACKAGES = ("jax", "jaxlib", "equinox", "optimistix", "lineax", "interpax", "numpy")


class Array:
    """Where an output array goes in the kept output structure."""


class Unkeyable(Exception):
    """Static data another process may not reproduce (user code, an address)."""


# Code whose behaviour the key covers: ctjax's source (digest) and these libraries' versions.
_KNOWN = ("ctjax", "builtins", *PACKAGES, "lineax", "jaxtyping", "numpy")
_PLAIN = (type(None), bool, int, float, complex, str, bytes)


def _known(thing) -> bool:
    return getattr(thing, "__module__", "").split(".")[0] in _KNOWN


def keyed(value) -> str:
    """Static data as text that another process reproduces exactly; raises `Unkeyable`
    for anything whose behaviour the key does not cover (code outside ctjax and its
    libraries, objects shown by address)."""
    if isinstance(value, _PLAIN):
        return repr(value)
    if isinstance(value, (tuple, list, frozenset)):
        return f"{type(value).__name__}({','.join(keyed(v) for v in value)})"
    if isinstance(value, dict):
        return f"dict({','.join(f'{keyed(k)}:{keyed(v)}' for k, v in value.items())})"
    if isinstance(value, (types.FunctionType, type)):
        if _known(value) and "<" not in value.__qualname__:
            return f"{value.__module__}.{value.__qualname__}"
        raise Unkeyable
    text = repr(value)
    if not _known(type(value)) or " at 0x" in text:
        raise Unkeyable
    return f"{type(value).__module__}.{type(value).__qualname__}:{text}"


def structure(treedef) -> str:
    """A pytree structure as text: node types, their static data, the leaves' places."""
    data = treedef.node_data()
    if data is None:
        return "*"
    kind, aux = data
    children = ",".join(structure(child) for child in treedef.children())
    return f"{keyed(kind)}[{keyed(aux)}]({children})"


# The skeleton in JSON (see the module doc). Libraries whose classes and constants it may
# name: the key covers their versions, and naming one imports or runs nothing of theirs.
_LIBRARIES = ("ctjax", *PACKAGES, "jaxtyping")
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
    """`module:qualname` for `_named`; raises `Unkeyable` where none finds `thing`."""
    name = f"{getattr(thing, '__module__', None)}:{getattr(thing, '__qualname__', None)}"
    try:
        if _named(name) is thing:
            return name
    except (KeyError, TypeError, ValueError):
        pass
    raise Unkeyable


def _constant(name: str):
    """The module-level constant `module:name` (equinox's MISSING): data of a type that
    module defines, neither a class, a function nor anything else callable."""
    module, _, attribute = name.partition(":")
    value = vars(_library(module))[attribute]
    if type(value).__module__ != module or callable(value):
        raise ValueError(f"not a constant: {name}")
    return value


def _encoded(value):
    """Static data as JSON data (see the module doc); raises `Unkeyable` for anything
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
    raise Unkeyable


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


def read_skeleton(data):
    """The output skeleton `skeleton_data` wrote; raises where `data` is not one."""
    treedef = _decoded_tree(data["tree"])
    parts = [Array() if leaf == {"array": None} else _decoded(leaf) for leaf in data["leaves"]]
    skeleton = jax.tree.unflatten(treedef, parts)
    # Node types' unflattening accepts some malformed structures (a None with a child, a
    # dict's keys out of order): what does not flatten back to itself is not a skeleton.
    again, structure = jax.tree.flatten(skeleton)
    if structure != treedef or len(again) != len(parts):
        raise ValueError("not an output skeleton")
    if any(a is not b for a, b in zip(again, parts, strict=True)):
        raise ValueError("not an output skeleton")
    return skeleton


def skeleton_data(skeleton) -> dict:
    """An output skeleton (`_Program`) as JSON data; raises `Unkeyable` where it holds
    anything the format does not describe, or it does not read back the same."""
    parts, treedef = jax.tree.flatten(skeleton)
    data = {
        "tree": _encoded_tree(treedef),
        "leaves": [{"array": None} if isinstance(p, Array) else _encoded(p) for p in parts],
    }
    # A kept program must rebuild exactly the output it was traced for: a name another
    # object answers to, or a type JSON does not tell apart, is caught here, not later.
    try:
        again, structure = jax.tree.flatten(read_skeleton(json.loads(json.dumps(data))))
        same = structure == treedef and all(
            isinstance(a, Array) == isinstance(b, Array)
            and (isinstance(a, Array) or (type(a) is type(b) and keyed(a) == keyed(b)))
            for a, b in zip(parts, again, strict=True)
        )
    except Exception as error:
        raise Unkeyable from error
    if not same:
        raise Unkeyable
    return data
