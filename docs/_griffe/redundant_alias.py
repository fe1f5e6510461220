"""Griffe extension for the API pages: `from ._module import name as name`, the form every
`ctjax` `__init__.py` uses to re-export its public names, marks `name` as public (griffe
takes an imported name as private unless a module's `__all__` lists it)."""

import ast
from typing import Any

import griffe


class RedundantAliasIsPublic(griffe.Extension):
    def on_alias_instance(self, *, node: Any, alias: griffe.Alias, **kwargs: Any) -> None:
        if isinstance(node, ast.ImportFrom | ast.Import) and any(
            name.asname == name.name == alias.name for name in node.names
        ):
            alias.public = True
