"""Blender parity: the same twin rendered by Cycles (CPU, in a subprocess) and by synth agree to
<= 2 8-bit levels (mean absolute) and <= 0.01 rad RMS decoded phase, on a plane and on the ball."""
import sys

import pytest

from synth.blender_twin import blender_available

pytestmark = [pytest.mark.blender, pytest.mark.skipif(not blender_available(sys.executable),
                                                      reason="bpy not installed (make test installs it)")]


@pytest.mark.parametrize("kind", ["plane", "sphere"])
def test_blender_parity_within_2_levels_and_0p01_rad(kind):
    from experiments.blender_parity import parity

    r = parity(kind, scale=4, steps=12, frequency=48, python=sys.executable)
    assert r["size"] == (160, 120)
    assert r["pixels"] > (15000 if kind == "plane" else 800)
    assert r["mad_8bit"] <= 2.0, r["mad_8bit"]
    assert r["phase_rms_rad"] <= 0.01, r["phase_rms_rad"]
