"""sltwin twin_mapping: calibration <-> digital-twin (Blender) parameters, and Blender export.

- ``to_twin(system)`` / ``from_twin(twin)``: system level; ``device_to_twin`` / ``twin_to_device``.
- ``write_blender_script(twin, path)``: a self-contained script that builds the twin in Blender.
- ``compare_with_table_s3(twin)``: our values beside the paper's printed table S3.
"""
from .blender_export import blender_script, write_blender_script  # noqa: F401
from .datasheets import BASLER_ACA640_750UM, DLP4500, Datasheet  # noqa: F401
from .errors import TwinError  # noqa: F401
from .mapping import device_to_twin, twin_to_device  # noqa: F401
from .paper import check_table_s2_rotations, compare_with_table_s3  # noqa: F401
from .twin import from_twin, read_twin_json, to_twin, write_twin_json  # noqa: F401
