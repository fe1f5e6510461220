"""`python -m ctjax.cli`, as the `ctjax` command."""

from . import run

run()
