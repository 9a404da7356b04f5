import time, torch, cProfile, pstats
torch.set_num_threads(2)
from bench.synth_speed import _scenes, _Quiet
from synth.geometry import compute_geometry
scene = list(_scenes())[2][1]
g = compute_geometry(scene, log=_Quiet())
g = compute_geometry(scene, log=_Quiet())
print({k: round(v*1000,1) for k,v in g.timings.items()})
cProfile.run("compute_geometry(scene, log=_Quiet())", "/tmp/prof.out")
pstats.Stats("/tmp/prof.out").sort_stats("tottime").print_stats(15)
