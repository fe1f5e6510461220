"""Every `ctjax` command except `batch`, one module each with the command's parser beside
its body; what several share (`_args`); how one runs (`_runner.execute`).

`COMMANDS` maps each command's name to the function that adds its parser (`run`, its body,
among the parser's defaults), in the order `ctjax --help` lists them.

This package is below both `ctjax.cli` (the `ctjax` program: these commands and `batch`)
and `ctjax.batch` (which runs some of them on each capture, as steps): neither of those
imports the other to run a command, and nothing here imports either. Each command imports
what it computes with when its parser is built or when it runs, not at import: building
the parser for `ctjax --help` stays quick.
"""

from ._calibrate_light import add_calibrate_light_parser
from ._diagnose import add_diagnose_parser
from ._evaluate import add_evaluate_parser
from ._fit import add_fit_parser
from ._import import add_import_parser
from ._masks import add_masks_parser
from ._reconstruct import add_reconstruct_parser
from ._runner import AddParser
from ._synth import add_demo_parser, add_synth_parser

COMMANDS: dict[str, AddParser] = {
    "synth": add_synth_parser,
    "import": add_import_parser,
    "masks": add_masks_parser,
    "reconstruct": add_reconstruct_parser,
    "fit": add_fit_parser,
    "diagnose": add_diagnose_parser,
    "calibrate-light": add_calibrate_light_parser,
    "evaluate": add_evaluate_parser,
    "demo": add_demo_parser,
}
