import time, torch
torch.set_num_threads(2)
from bench.synth_speed import _scenes, _Quiet
from synth.geometry import camera_rays, compute_geometry
from synth import raycast
import synth._raycast_kernel as K
scene = list(_scenes())[2][1]
rays, ok = camera_rays(scene.system.camera, True)
compute_geometry(scene, log=_Quiet())
T = {}
def wrap(mod, name):
    f = getattr(mod, name)
    def g(*a, **k):
        t0 = time.perf_counter(); r = f(*a, **k); T[name] = T.get(name, 0) + time.perf_counter() - t0; return r
    setattr(mod, name, g)
for n in ("_sort_rays", "_triangle_boxes", "_fill_refs", "_trace_cells", "_chunk_end", "nearest_hits_numba"):
    wrap(K, n)
for o in scene.objects:
    t0 = time.perf_counter(); h = o.intersect(rays); print(o.name, "intersect", time.perf_counter() - t0)
print({k: round(v * 1000, 1) for k, v in T.items()})
