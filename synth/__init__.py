"""sltwin synth: a torch renderer of fringe images from the digital twin, with ground truth.

Public surface:

- scenes: ``Scene``, ``load_scene``, ``scene_from_dict``, ``ideal_system``,
  ``DEFAULT_BALL_RADIUS_MM``; objects ``Plane``, ``Board``, ``Sphere``, ``Mesh``; boards as
  printed: ``BoardTexture`` (a ``calib.board.Board`` with its margin and albedo; the board type
  itself lives in calib), ``BoardSpec`` (one from flat keys); meshes ``load_mesh``,
  ``steps_mesh``, ``heightfield_mesh``, ``blobs_heights``; patterns ``PatternSpec``,
  ``phase_sequence``, ``gray_sequence``; ``Effects``, ``effects_from_table``, ``Defocus``,
  ``Noise``.
- rendering: ``render`` -> ``RenderResult``; ``compute_geometry`` -> ``Geometry`` (the reusable
  geometry stage).
- output: ``write_render`` (PNG + HDF5 ground truth), ``render_board_session`` (a calibration
  session in the capture layout).
- ``SynthError`` (a ValueError).

The render plan goes to the `synth` logger at DEBUG, progress at INFO.
"""
from .scenes.board_session import render_board_session
from .scenes.boards import BoardSpec, BoardTexture
from .effects.spec import Defocus, Effects, Noise, effects_from_table
from .errors import SynthError
from .renderer.geometry import Geometry, compute_geometry
from .scenes.meshes import blobs_heights, heightfield_mesh, load_mesh, steps_mesh
from .scenes.objects import Board, Mesh, Plane, Sphere
from .renderer.output import write_render
from .renderer.render import RenderResult, render
from .scenes.scene import DEFAULT_BALL_RADIUS_MM, Scene, ideal_system, load_scene, scene_from_dict
from .scenes.sequence import PatternSpec, gray_sequence, phase_sequence

__all__ = [
    "Scene", "load_scene", "scene_from_dict", "ideal_system", "DEFAULT_BALL_RADIUS_MM",
    "Plane", "Board", "Sphere", "Mesh", "BoardTexture", "BoardSpec",
    "load_mesh", "steps_mesh", "heightfield_mesh", "blobs_heights",
    "PatternSpec", "phase_sequence", "gray_sequence", "Effects", "effects_from_table", "Defocus", "Noise",
    "render", "RenderResult", "compute_geometry", "Geometry",
    "write_render", "render_board_session",
    "SynthError",
]
