"""Any model as JSON, by walking its Modules: a new lobe, light or effect serialises itself.

Two views of one model:

- `to_json(module)`: the whole tree, `{"class": "PointLight", "position_mm": [...], ...}`,
  every field (static ones too, when they are plain values), arrays as lists.
- `named_parameters(module)`: the parameters a field declares a name for
  (`eqx.field(metadata=named("sigma", ...))`), in the paper's words: `rho_tilde`,
  `F_tilde`, `sigma`, `offset_mm`... The first field of a name keeps it; later ones get
  `_2`, `_3` (a second specular lobe: `F_tilde_2`, `sigma_2`). These are the keys the
  estimators' JSON documents, found whatever the lobes' order.
"""

import dataclasses

import equinox as eqx
import numpy as np

JSON = dict | list | float | int | str | bool | None


def _value(x) -> JSON:
    if eqx.is_array(x) or isinstance(x, np.generic):
        array = np.asarray(x)
        if array.dtype == bool:
            return array.tolist()
        if array.size > 64:  # a map (a light field's directions): its shape, not its values
            return {"shape": list(array.shape), "dtype": str(array.dtype)}
        return array.astype(float).tolist() if array.dtype.kind == "f" else array.tolist()
    if isinstance(x, str | bool | int | float) or x is None:
        return x
    if isinstance(x, eqx.Module | tuple | list):
        return to_json(x)
    return type(x).__name__  # a function or another object: named, not serialised


def to_json(module) -> JSON:
    """The model tree as JSON: class names and every field, recursively."""
    if isinstance(module, eqx.Module):
        out: dict = {"class": type(module).__name__}
        for field in dataclasses.fields(module):
            value = getattr(module, field.name)
            if field.metadata.get("static", False) and not isinstance(
                value, str | bool | int | float | tuple
            ):
                continue  # a function or a config object: not data
            out[field.name] = _value(value)
        return out
    if isinstance(module, tuple | list):
        return [_value(m) for m in module]
    return _value(module)


def _walk_named(node, out: dict, paths: dict, path: str = "") -> None:
    if isinstance(node, eqx.Module):
        for field in dataclasses.fields(node):
            value = getattr(node, field.name)
            name = field.metadata.get("name")
            child = f"{path}.{field.name}" if path else field.name
            if name is not None and eqx.is_array(value):
                key, index = name, 1
                while key in out:
                    index += 1
                    key = f"{name}_{index}"
                out[key] = _value(value)
                paths[child] = key
            else:
                _walk_named(value, out, paths, child)
    elif isinstance(node, tuple | list):
        for index, value in enumerate(node):
            _walk_named(value, out, paths, f"{path}[{index}]")


def named_parameters(module) -> dict[str, JSON]:
    """The named parameters of a model (`rho_tilde`, `F_tilde`, `sigma`, ...), in the order
    of the tree: the paper's view of any model."""
    out: dict[str, JSON] = {}
    _walk_named(module, out, {})
    return out


def paper_names(module) -> dict[str, str]:
    """The named parameters' names by their dotted field names (`array_fields`' keys):
    `{"brdf.lobes[1].weight": "F_tilde", "light.position_mm": "offset_mm", ...}`."""
    paths: dict[str, str] = {}
    _walk_named(module, {}, paths)
    return paths


def _walk_arrays(node, name: str, out: dict) -> None:
    if isinstance(node, eqx.Module):
        for field in dataclasses.fields(node):
            child = f"{name}.{field.name}" if name else field.name
            _walk_arrays(getattr(node, field.name), child, out)
    elif isinstance(node, tuple | list):
        for index, value in enumerate(node):
            _walk_arrays(value, f"{name}[{index}]", out)
    elif eqx.is_array(node) or isinstance(node, str):
        out[name] = _value(node)


def array_fields(module) -> dict[str, JSON]:
    """Every array (and string) field of a model by its dotted name (`light.position_mm`,
    `brdf.lobes[k].distribution.sigma`), fixed ones too, as JSON values."""
    out: dict[str, JSON] = {}
    _walk_arrays(module, "", out)
    return out


def falloff_json(light) -> dict[str, JSON]:
    """A light's falloff factors by name: `{"inverse_square": {"reference_mm": 70}, ...}`."""
    out = {}
    for factor in getattr(light, "falloff", ()):
        fields = to_json(factor)
        out[getattr(factor, "name", fields.pop("class"))] = {
            k: v for k, v in fields.items() if k != "class"
        }
    return out
