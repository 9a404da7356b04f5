"""Running Blender from the toolkit: the one probe (:func:`blender_available`) and the one way to
run a job in a Python that has ``bpy`` (:func:`run_in_blender`), always in a SUBPROCESS: the
toolkit never imports bpy itself.

A job runs ``blender_driver.py`` (beside this module) with the twin's exported scene script
(:mod:`twin_mapping.blender_export`) and a JSON configuration; the driver builds the twin and
does the job: ``check`` (project points through Blender's cameras, :mod:`twin_mapping.blender_check`)
or ``render`` (Lambertian surfaces lit by the projector's pattern, :mod:`synth.blender_twin`).
"""
from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import time
from importlib import resources
from pathlib import Path

from .errors import TwinError

JOBS = ("check", "render")


def blender_available(python: str | None = None) -> bool:
    """True when ``bpy`` can be imported: by this interpreter (``python`` None or this one; a
    module lookup, no import) or by the interpreter ``python`` (a subprocess imports it)."""
    if python is None or python == sys.executable:
        return importlib.util.find_spec("bpy") is not None
    try:
        r = subprocess.run([python, "-c", "import bpy"], capture_output=True, timeout=120)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return r.returncode == 0


def run_in_blender(job: str, scene_script, config: dict, workdir, *, python: str | None = None,
                   timeout: float = 900) -> float:
    """Run ``job`` with the driver: writes ``workdir/config.json`` (``config`` plus the job) and
    runs ``python blender_driver.py SCENE.py CONFIG.json``. Returns the subprocess's wall time (s).
    Raises TwinError when bpy is missing or the job fails (with the end of Blender's stderr)."""
    if job not in JOBS:
        raise TwinError(f"Blender job: expected one of {JOBS}, got {job!r}")
    python = python or sys.executable
    if not blender_available(python):
        raise TwinError(f"Blender as a Python module (bpy) is not installed in {python}; "
                        "`make test` installs it (pip install bpy==4.5.15)")
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    cfg_path = workdir / "config.json"
    cfg_path.write_text(json.dumps({**config, "job": job}))
    driver = resources.files("twin_mapping").joinpath("blender_driver.py")
    t0 = time.perf_counter()
    try:
        r = subprocess.run([python, str(driver), str(scene_script), str(cfg_path)], capture_output=True, text=True,
                           timeout=timeout)
    except subprocess.TimeoutExpired:
        raise TwinError(f"the Blender {job} job did not finish within {timeout:g} s") from None
    if r.returncode != 0:
        raise TwinError(f"the Blender {job} job failed (exit {r.returncode}):\n{r.stderr[-3000:]}")
    return time.perf_counter() - t0
