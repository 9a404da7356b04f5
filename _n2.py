import time, torch
torch.set_num_threads(2)
from synth.effects import Noise
from synth.sensor import add_noise, _add_noise_torch
torch.manual_seed(1)
img = torch.rand(72, 480, 640) * 0.8
img[:, :100] = 0
img[:, 100:110] = torch.rand(72, 10, 640) * 0.004   # Poisson region
img[0, 0, :5] = -0.1
noise = Noise()
a = add_noise(img.clone(), noise, torch.Generator().manual_seed(0))
b = _add_noise_torch(img.clone(), noise, torch.Generator().manual_seed(0))
print("bit-identical", torch.equal(a, b), float((a - b).abs().max()))
for f in (add_noise, _add_noise_torch, add_noise, _add_noise_torch):
    x = img.clone(); t0 = time.perf_counter(); f(x, noise, torch.Generator().manual_seed(0)); print(f.__name__, time.perf_counter() - t0)
d = (a != b)
print(d.sum(), d.nonzero()[:5], a[d][:5], b[d][:5], img[d][:5])
