"""Inputs of the learned-unwrapping commands, checked before any work: a file of the right kind
is given where one is expected, or the command is refused naming the option, the file, what it
is and what was expected (``calib eval``, ``calib unwrap --model``, ``calib report --learned-*``).

- :func:`dataset_files`: fringe-order datasets (``calib export``); a phase file (``unwrap.h5``),
  a render's ``truth.h5``, a truncated or foreign HDF5 file are named as such;
- :func:`model_of_kind`: a checkpoint of the expected kind (physics-aware or prior-free);
- :func:`run_folder`: a training run folder (``calib train -o RUN``).

All raise :class:`sltwin.errors.CommandError`. Heavy imports (h5py, torch) happen inside.
"""
from __future__ import annotations

from pathlib import Path

from .errors import CommandError

KIND_NAMES = {"physics": "physics-aware", "prior_free": "prior-free"}


def _what_hdf5(h5) -> str:
    """A short description of an HDF5 file that is not a fringe-order dataset."""
    if "depth" in h5 and "masks" in h5:
        return "a render's ground truth (calib render's truth.h5)"
    if any(o in h5 and "phase" in h5[o] for o in ("v", "h")):
        return "a phase file (calib unwrap's unwrap.h5, phase maps of one capture)"
    return f"an HDF5 file of another kind (top-level entries {sorted(h5.keys())[:5]})"


def dataset_files(paths, option: str, *, need_reference: bool = False, needs: str = "") -> list:
    """Each of ``paths`` must be a complete fringe-order dataset (``calib export``); with
    ``need_reference`` it must hold reference orders (``calib export --capture``). ``needs`` says
    in the message what the option needs. Returns the paths."""
    import h5py

    from unwrap.dataset_schema import check_schema
    from unwrap.errors import DatasetSchemaError

    needs = needs or "a fringe-order dataset written by calib export"
    for p in paths:
        path = Path(p)
        if not path.is_file():
            raise CommandError(f"{option} {p}: no such dataset file ({needs})")
        try:
            with h5py.File(path, "r") as h5:
                if "schema" not in h5.attrs:
                    raise CommandError(f"{option} {p}: is {_what_hdf5(h5)}, not a fringe-order dataset; {option} "
                                       f"needs {needs}")
                check_schema(h5, str(path))
                # a capture's reference orders, or a twin file's geometric orders (exact by construction)
                refs = [o for o in ("v", "h") if f"{o}/reference_order" in h5 or f"{o}/order" in h5]
        except OSError as exc:
            raise CommandError(f"{option} {p}: not a readable HDF5 file (truncated, or not HDF5: "
                               f"{str(exc).split('(')[0].strip()}); {option} needs {needs}") from None
        except DatasetSchemaError as exc:
            raise CommandError(f"{option} {exc}") from None
        if need_reference and not refs:
            raise CommandError(f"{option} {p}: a fringe-order dataset without reference orders; {option} needs "
                               f"{needs}")
    return list(paths)


def model_of_kind(path, kind: str, option: str):
    """The checkpoint ``path`` (``learned``/``default``: the shipped model) must be of ``kind``
    (``physics`` or ``prior_free``); returns the path to load."""
    from unwrap.learned.checkpoint import read_checkpoint
    from unwrap.learned.infer import shipped_model_path

    if path in ("learned", "default"):
        path = shipped_model_path()
    got = read_checkpoint(path)["arch"].get("kind")
    if got != kind:
        other = {"physics": "--model", "prior_free": "--prior-free"}
        hint = f" (give it as {other[got]})" if option in ("--model", "--prior-free", "--mse-only") and got in other \
            else ""
        raise CommandError(f"{option} {path}: a {KIND_NAMES.get(got, got)} model; {option} takes a "
                           f"{KIND_NAMES[kind]} one{hint}")
    return path


def run_folder(path, option: str) -> str:
    """``path`` must be a training run folder (its ``metrics.json``, written when a run ends)."""
    p = Path(path)
    if not p.is_dir():
        raise CommandError(f"{option} {path}: no such folder (a run folder of calib train -o RUN)")
    if not (p / "metrics.json").is_file():
        what = "a run that never finished a session" if (p / "last.pt").is_file() else "not a run folder"
        raise CommandError(f"{option} {path}: no metrics.json there ({what}); give a run folder of calib train")
    return str(path)


#: Names that stand for the built-in system (the paper's real system) where a calibration is asked.
BUILTIN_NAMES = ("builtin", "built-in", "default")


def calibration_paths(values) -> list:
    """Calibration file arguments for ``calib.load_system``: a lone ``builtin`` (or ``built-in``,
    ``default``) names the built-in system (no file), unless a file of that name exists."""
    values = list(values or [])
    if len(values) == 1 and values[0].lower() in BUILTIN_NAMES and not Path(values[0]).exists():
        return []
    return values
