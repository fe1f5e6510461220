"""How a `ctjax` command runs, from its words to its exit status: the parser (bad options on
one line, every default shown), JAX set up for estimation, and a `CtjaxError` or an
interrupt reported on one line (`execute`).

`ctjax.cli` runs every command this way, and `ctjax.batch` its steps: the same parse, the
same set-up and the same one-line errors, which a batch's summary row quotes.
"""

import argparse
import sys
from collections.abc import Callable, Iterable

from .._errors import CtjaxError

# Adds one command's parser (its options, and `run`: its body) to the subcommands.
AddParser = Callable[[argparse._SubParsersAction], None]


class Parser(argparse.ArgumentParser):
    """argparse with bad options reported on one line (`ctjax fit: error: ...`), status 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}\n")


def show_defaults(parser: argparse.ArgumentParser) -> None:
    """Every option's help ends with its default, where it has one and does not say it."""
    for action in parser._actions:
        if action.help is None or action.help == argparse.SUPPRESS or "default" in action.help:
            continue
        if action.default in (None, False, [], argparse.SUPPRESS) or not action.option_strings:
            continue
        value = action.default
        if isinstance(value, list | tuple):
            value = " ".join(str(v) for v in value)
        action.help += f" (default: {value})"


def parser_of(commands: Iterable[AddParser]) -> argparse.ArgumentParser:
    """The `ctjax` parser with these commands, in this order (the order of `--help`)."""
    parser = Parser(
        prog="ctjax",
        description="Cook-Torrance reflectance and laparoscope light from images (JAX).",
    )
    subcommands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add_parser in commands:
        add_parser(subcommands)
    for command in subcommands.choices.values():
        show_defaults(command)
    return parser


def execute(parser: argparse.ArgumentParser, argv: list[str] | None = None) -> int:
    """Run the command `argv` names (`sys.argv[1:]` when None) with `parser` (`parser_of`);
    returns its exit status: 0, 2 for bad input (one line on stderr), 130 if interrupted."""
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit:  # bad options (status 2, one line), --help (status 0)
        return exit.code if isinstance(exit.code, int) else 0
    import jax

    from .._performance import enable_compilation_cache, tune_malloc, tune_xla
    from .._programs import loading_ahead

    # Estimation in double precision; renders stay in the dtype of their inputs.
    jax.config.update("jax_enable_x64", True)
    tune_malloc()
    tune_xla()
    enable_compilation_cache()
    try:
        with loading_ahead(args.command, argv):
            return args.run(args)
    except CtjaxError as error:
        print(f"ctjax {args.command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"ctjax {args.command}: interrupted", file=sys.stderr)
        return 130
