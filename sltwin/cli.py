"""The ``calib`` command line: one dispatcher over one module per sub-command.

Adding a command: write a module in ``sltwin/commands/`` with

- ``HELP``: one line of help;
- ``add_arguments(parser)``: its options (argparse);
- ``run(args) -> int``: parse nothing, call library functions, print results, return the exit code;
- optionally ``exit_codes()``: ``[(error type, exit code, message prefix), ...]`` for errors that
  deserve their own exit code (``calib run``; a function, so that the error types are imported
  only when an error happens), and ``LOG_FORMAT`` (how progress lines look);

then import it below and add ``("name", module)`` to ``COMMANDS``. A command module imports only
light modules at top level (numpy, error types) and the heavy ones (torch, cv2, casadi) inside
``run``, so that ``calib --help`` stays fast.

Errors: every package's errors derive from one root per package (``calib.errors.CalibError``,
``unwrap.errors.UnwrapError``, ``twin_mapping.errors.TwinError``, ``synth.errors.SynthError``,
``reports.errors.ReportError``, ``sltwin.errors.CommandError``), all ``ValueError`` subclasses.
``main`` maps them, here and only here, to exit code 2 (or the command's ``exit_codes()``) with the
message on stderr, never a traceback (not even one quoted in a message, as a data-loading worker's
error carries); so do file-system errors (``OSError``: the message names the path, or the output
being written). Anything else is a bug: exit code 1 and a one-line message asking for ``--debug``, which
shows the traceback (of every error) for a bug report. Ctrl-C ends with 130. Outputs are checked
before any work and locked while the command runs (:func:`sltwin.outputs.claim`; released when it
ends, however it ends).

Progress: library packages log through one logger each (``calib``, ``unwrap``, ``twin_mapping``,
``synth``, ``experiments``, ``reports``); ``main`` shows their INFO lines on stderr for the duration of the command
(``-q`` where a command has it: warnings only; ``--debug``: everything).
"""
from __future__ import annotations

import argparse
import logging
import platform
import sys
import traceback

from .commands import (convert, demo, evaluate, export, export_model, plan_fringes, reconstruct, render,
                       render_board, report, run, train, twin, unwrap)
from .outputs import release_all

#: (sub-command, module), in the order ``calib --help`` lists them.
COMMANDS = [
    ("run", run),
    ("reconstruct", reconstruct),
    ("twin", twin),
    ("convert", convert),
    ("report", report),
    ("demo", demo),
    ("unwrap", unwrap),
    ("plan-fringes", plan_fringes),
    ("render", render),
    ("render-board", render_board),
    ("export", export),
    ("train", train),
    ("eval", evaluate),
    ("export-model", export_model),
]

#: Loggers whose progress the command line shows.
LOGGERS = ("calib", "unwrap", "twin_mapping", "synth", "experiments", "reports", "sltwin")


def version() -> str:
    """The installed sltwin version (``setup.cfg``), or "unknown" when it is not installed."""
    from importlib import metadata

    try:
        return metadata.version("sltwin")
    except metadata.PackageNotFoundError:
        return "unknown"


def _add_debug(parser, default) -> None:
    parser.add_argument("-v", "--debug", action="store_true", default=default,
                        help="debug messages of every package, and the traceback of an error (for bug reports)")


class _VersionAction(argparse.Action):
    """``--version``: the installed version, looked up only when asked (``importlib.metadata``
    costs every command 0.05-0.2 s of start-up)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS,
                 help="show the program's version number and exit"):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"calib (sltwin) {version()}")
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="calib", description="sltwin: structured-light calibration, digital "
                                     "twin, renderer and phase unwrapping")
    parser.add_argument("--version", action=_VersionAction)
    _add_debug(parser, False)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, module in COMMANDS:
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        p.set_defaults(_module=module)
        _add_debug(p, argparse.SUPPRESS)   # ``calib run ... --debug`` works as ``calib --debug run ...``
        module.add_arguments(p)
    return parser


def exit_code(module, exc: Exception) -> tuple[int, str]:
    """(exit code, message prefix) of a toolkit error raised by a command: the command's own
    ``exit_codes()`` entry for the error's type, else 2."""
    for error_type, code, prefix in getattr(module, "exit_codes", list)():
        if isinstance(exc, error_type):
            return code, prefix
    return 2, ""


def _show_progress(args) -> tuple[logging.Handler, dict]:
    """Send the packages' log records to stderr while the command runs; returns the handler and
    the loggers' previous levels, which ``main`` restores."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(getattr(args._module, "LOG_FORMAT", "%(message)s")))
    level = logging.DEBUG if args.debug else logging.WARNING if getattr(args, "quiet", False) else logging.INFO
    handler.setLevel(level)   # also for a package's child logger that sets its own level (training's run log)
    saved = {}
    for name in LOGGERS:
        logger = logging.getLogger(name)
        saved[name] = logger.level
        logger.addHandler(handler)
        logger.setLevel(level)
    return handler, saved


def _versions() -> str:
    """One line for a bug report: sltwin, Python, numpy and the platform."""
    import numpy

    return (f"sltwin {version()}, Python {platform.python_version()}, numpy {numpy.__version__}, "
            f"{platform.platform()}")


def without_traceback(message: str) -> str:
    """``message`` without a traceback quoted inside it (a data-loading worker's error carries
    its worker's traceback in its text): the text before it and the traceback's last line.

    >>> without_traceback("Caught ValueError in DataLoader worker process 0.\\nOriginal Traceback (most recent "
    ...                   "call last):\\n  File \\"x.py\\", line 1\\nValueError: x.h5: bad")
    'Caught ValueError in DataLoader worker process 0: ValueError: x.h5: bad'
    """
    head, sep, tail = message.partition("Traceback (most recent call last):")
    if not sep:
        return message
    head = head.replace("Original", "").strip().rstrip(".:")
    last = [line.strip() for line in tail.strip().splitlines() if line.strip()]
    return f"{head}: {last[-1]}" if last else head


def _torch_out_of_memory(exc: BaseException) -> bool:
    """Whether ``exc`` is torch's allocator out of memory: a RuntimeError, not a MemoryError (its CPU
    allocator's "DefaultCPUAllocator: can't allocate memory", torch.OutOfMemoryError on a GPU)."""
    return isinstance(exc, RuntimeError) and (type(exc).__name__ == "OutOfMemoryError"
                                              or ("DefaultCPUAllocator" in str(exc) and "memory" in str(exc)))


def _out_of_memory(args, exc: BaseException) -> int:
    """Report running out of memory (a resource, not a bug: say so, how much where the allocator said,
    and what to try); exit status 2."""
    if args.debug:
        traceback.print_exc()
    detail = without_traceback(str(exc)).strip().splitlines()
    detail = f": {detail[0][:200]}" if detail else ""
    hint = " (try --low-memory)" if getattr(args, "low_memory", True) is False else ""
    print(f"calib {args.command}: error: out of memory{hint}{detail}", file=sys.stderr)
    return 2


def main(argv=None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    trailing = getattr(getattr(args, "_module", None), "TRAILING_ITEMS", None)
    if extra and trailing and not any(e.startswith("-") for e in extra):
        setattr(args, trailing, list(getattr(args, trailing)) + extra)   # ``calib train CONFIG -o RUN key=value``
    elif extra:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    handler, levels = _show_progress(args)
    if args.debug:
        logging.getLogger("sltwin").debug(f"calib {args.command}: {_versions()}")
    try:
        return int(args._module.run(args) or 0)
    except (ValueError, OSError) as exc:   # toolkit errors are ValueErrors; OSError names its path
        if args.debug:
            traceback.print_exc()
        code, prefix = exit_code(args._module, exc)
        message = without_traceback(str(exc))
        output = getattr(args, "output", None)
        if isinstance(exc, OSError) and not exc.filename and output:   # e.g. a full disk: say where
            message += f" (while writing {' '.join(map(str, output)) if isinstance(output, list) else output})"
        print(f"calib {args.command}: error: {prefix}{message}", file=sys.stderr)
        return code
    except MemoryError as exc:              # a resource, not a bug: say so and what to try
        return _out_of_memory(args, exc)
    except Exception as exc:                # a bug: one line, the traceback with --debug
        if _torch_out_of_memory(exc):
            return _out_of_memory(args, exc)
        if args.debug:
            raise
        print(f"calib {args.command}: internal error: {type(exc).__name__}: {without_traceback(str(exc))}\n"
              f"  This is a bug in sltwin: run the same command with --debug for the traceback and "
              "report it.", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"calib {args.command}: interrupted", file=sys.stderr)
        return 130
    finally:
        release_all()
        for name, level in levels.items():
            logging.getLogger(name).removeHandler(handler)
            logging.getLogger(name).setLevel(level)


if __name__ == "__main__":
    sys.exit(main())
