"""Measure reconstruct's fused CPU path against the tensor ops and kornia (README, "The fused CPU path").

Part 1: 1280x720 uniform pan, float32, S=15, forward and forward+backward, both frameworks.
Part 2: adaptive sampling on a 512x512 scene that is 90 % still, fused and tensor ops.
Run: PYTHONPATH=. python scripts/measure_fused.py
"""
import time, numpy as np, torch, jax, jax.numpy as jnp, kornia
jax.config.update("jax_enable_x64", False)
import torch_impl, jax_impl
from diffblur.bench import uniform_scene, _inputs
x = _inputs(uniform_scene(height=720, width=1280))
def med(f, n=3):
    f(); ts=[]
    for _ in range(n):
        t0=time.perf_counter(); f(); ts.append(time.perf_counter()-t0)
    return round(float(np.median(ts))*1e3)
res = {}
tc, tv, td = (torch.from_numpy(x[k]) for k in ("color","velocity","depth"))
def tfb(fused, samples=15, **kw):
    def run():
        c, v, d = (t.clone().requires_grad_() for t in (tc, tv, td))
        torch_impl.reconstruct(c, v, d, samples=samples, fused=fused, **kw).sum().backward()
    return run
for fused in (True, False):
    res[f"torch fused={fused} fwd"] = med(lambda: torch_impl.reconstruct(tc, tv, td, samples=15, fused=fused))
    res[f"torch fused={fused} fwd+bwd"] = med(tfb(fused), 2 if not fused else 3)
res["torch fused S=31 fwd"] = med(lambda: torch_impl.reconstruct(tc, tv, td, samples=31, fused=True))
angle = torch.tensor(x["angle"])
res["kornia k31 fwd"] = med(lambda: kornia.filters.motion_blur(tc, 31, angle, 0.0, border_type="replicate", mode="bilinear"))
def kfb():
    c = tc.clone().requires_grad_(); a = angle.clone().requires_grad_()
    kornia.filters.motion_blur(c, 31, a, 0.0, border_type="replicate", mode="bilinear").sum().backward()
res["kornia k31 fwd+bwd"] = med(kfb)
jc, jv, jd = (jnp.asarray(x[k]) for k in ("color","velocity","depth"))
for fused in (True, False):
    f = jax.jit(lambda c,v,d: jax_impl.reconstruct(c,v,d, samples=15, fused=fused))
    g = jax.jit(jax.grad(lambda c,v,d: jnp.sum(jax_impl.reconstruct(c,v,d, samples=15, fused=fused)), argnums=(0,1,2)))
    t0=time.perf_counter(); jax.block_until_ready(f(jc,jv,jd)); res[f"jax fused={fused} compile+first fwd"] = round((time.perf_counter()-t0)*1e3)
    res[f"jax fused={fused} fwd"] = med(lambda: jax.block_until_ready(f(jc,jv,jd)))
    res[f"jax fused={fused} fwd+bwd"] = med(lambda: jax.block_until_ready(g(jc,jv,jd)), 2 if not fused else 3)
for k, v in res.items(): print(f"{k}: {v} ms", flush=True)


# Part 2
H = W = 512
rng = np.random.default_rng(0)
color = rng.random((1,3,H,W)).astype(np.float32)
vel = np.zeros((1,2,H,W), np.float32); vel[:, 0, 200:362, 200:362] = 8.0  # 162x162 ~ 10% of pixels
depth = np.ones((1,1,H,W), np.float32); depth[:, :, 200:362, 200:362] = 0.5
print("moving fraction", (vel[0,0]!=0).mean())
tc, tv, td = map(torch.from_numpy, (color, vel, depth))
jc, jv, jd = map(jnp.asarray, (color, vel, depth))
for name, fused in (("fused", None), ("tensor ops", False)):
    for fw in ("torch", "jax"):
        if fw == "torch":
            full = med(lambda: torch_impl.reconstruct(tc, tv, td, samples=15, fused=fused))
            ada = med(lambda: torch_impl.reconstruct(tc, tv, td, samples=15, adaptive=True, fused=fused))
            d = (torch_impl.reconstruct(tc, tv, td, samples=15, adaptive=True, fused=fused) - torch_impl.reconstruct(tc, tv, td, samples=15, fused=fused)).abs()
        else:
            if fused is None:
                f1 = jax.jit(lambda c,v,d: jax_impl.reconstruct(c,v,d, samples=15)); f2 = jax.jit(lambda c,v,d: jax_impl.reconstruct(c,v,d, samples=15, adaptive=True))
            else:
                f1 = jax.jit(lambda c,v,d: jax_impl.reconstruct(c,v,d, samples=15, fused=False)); f2 = lambda c,v,d: jax_impl.reconstruct(c,v,d, samples=15, adaptive=True, fused=False)
            full = med(lambda: jax.block_until_ready(f1(jc,jv,jd)))
            ada = med(lambda: jax.block_until_ready(f2(jc,jv,jd)))
            d = np.abs(np.asarray(f2(jc,jv,jd)) - np.asarray(f1(jc,jv,jd)))
        print(f"{name} {fw}: full {full:.1f} ms, adaptive {ada:.1f} ms, speed-up {full/ada:.1f}x, max diff {float(d.max()):.2e}", flush=True)
