"""sltwin application layer: the `calib` command line and the demo, above every library package.

The library packages (unwrap < calib < twin_mapping < synth < reports) hold no argparse and
import nothing from here. Each sub-command is one module of `sltwin.commands` that parses its
options and calls library functions; `sltwin.cli` registers them (its docstring says how to add
one).

Public surface:

- ``main``: the `calib` command (``main(["run", ...])`` returns the exit code).
- ``run_demo``: the demo's four steps (``calib demo``) from Python.
- ``CommandError``: an invalid option or input of a command (exit code 2).
"""
from .cli import main
from .demo import run_demo
from .errors import CommandError

__all__ = ["main", "run_demo", "CommandError"]
