"""sltwin twin_mapping: calibration <-> digital-twin (Blender) parameters, the paper's printed
tables, Blender export and check.

Public surface:

- ``to_twin`` / ``from_twin``: system level (``twin.json`` dictionary <-> ``calib.SystemModel``);
  ``device_to_twin`` / ``twin_to_device``: one device; ``read_twin_json`` / ``write_twin_json``.
- ``twin_with_paper``: the twin with the paper's table S3 beside it when the system is the paper's;
  ``format_twin_table``: it as text; ``is_papers_system``.
- the paper: ``compare_with_table_s3``, ``check_table_s2_rotations`` (every printed number lives
  in ``twin_mapping.paper_tables``).
- datasheets: ``Datasheet``, ``BASLER_ACA640_750UM``, ``DLP4500``.
- Blender: ``blender_script`` / ``write_blender_script`` (a self-contained scene script),
  ``blender_available``, ``check_twin_in_blender``.
- ``TwinError`` (a ValueError).
"""
from .blender_check import check_twin_in_blender
from .blender_export import blender_script, write_blender_script
from .blender_run import blender_available
from .datasheets import BASLER_ACA640_750UM, DLP4500, Datasheet
from .errors import TwinError
from .mapping import device_to_twin, twin_to_device
from .paper import check_table_s2_rotations, compare_with_table_s3
from .table import format_twin_table, is_papers_system, twin_with_paper
from .twin import from_twin, read_twin_json, to_twin, write_twin_json

__all__ = [
    "to_twin", "from_twin", "device_to_twin", "twin_to_device", "read_twin_json", "write_twin_json",
    "twin_with_paper", "format_twin_table", "is_papers_system",
    "compare_with_table_s3", "check_table_s2_rotations",
    "Datasheet", "BASLER_ACA640_750UM", "DLP4500",
    "blender_script", "write_blender_script", "blender_available", "check_twin_in_blender",
    "TwinError",
]
