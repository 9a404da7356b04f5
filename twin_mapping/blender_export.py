"""Write a self-contained Blender Python script that builds the twin scene.

The script is ``blender_template.py`` followed by the twin parameters as a JSON literal and a
``__main__`` block: ``blender --background --python scene.py [-- --save scene.blend]`` builds the
scene (and saves it when asked). Importing bpy is the script's business, never the toolkit's.
"""
from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

from unwrap.safe_output import write_text

_MAIN = '''

TWIN = json.loads(r"""{twin_json}""")

if __name__ == "__main__":
    import sys
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    objects = build_twin_scene(TWIN)
    if "--save" in argv:
        bpy.ops.wm.save_as_mainfile(filepath=argv[argv.index("--save") + 1])
    print("twin scene built:", ", ".join(sorted(objects)))
'''


def blender_script(twin: dict) -> str:
    """The text of the scene script for a twin dictionary."""
    body = resources.files("twin_mapping").joinpath("blender_template.py").read_text()
    body = body.replace("import math\n", "import json\nimport math\n", 1)
    return body + _MAIN.format(twin_json=json.dumps(twin, indent=1))


def write_blender_script(twin: dict, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, blender_script(twin))
    return path
