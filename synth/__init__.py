"""sltwin synth: a torch renderer of fringe images from the digital twin, with ground truth.

Public surface:

- scenes: ``Scene``, ``load_scene``, ``scene_from_dict``, ``ideal_system``; objects ``Plane``,
  ``Board``, ``Sphere``, ``Mesh``; ``BoardSpec``; meshes ``load_mesh``, ``steps_mesh``,
  ``heightfield_mesh``, ``blobs_heights``; patterns ``PatternSpec``, ``phase_sequence``,
  ``gray_sequence``; ``Effects``, ``Defocus``, ``Noise``.
- rendering: ``render`` -> ``RenderResult``; ``compute_geometry`` (the reusable geometry stage).
- output: ``write_render`` (PNG + HDF5 ground truth), ``render_board_session`` (a calibration
  session in the capture layout).
- ``SynthError``.
"""
from .boards import BoardSpec  # noqa: F401
from .effects import Defocus, Effects, Noise, effects_from_table  # noqa: F401
from .errors import SynthError  # noqa: F401
from .geometry import Geometry, compute_geometry  # noqa: F401
from .meshes import blobs_heights, heightfield_mesh, load_mesh, steps_mesh  # noqa: F401
from .objects import Board, Mesh, Plane, Sphere  # noqa: F401
from .render import RenderResult, render  # noqa: F401
from .scene import DEFAULT_BALL_RADIUS_MM, Scene, ideal_system, load_scene, scene_from_dict  # noqa: F401
from .sequence import PatternSpec, gray_sequence, phase_sequence  # noqa: F401
