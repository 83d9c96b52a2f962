"""PyTorch counterparts of the hash-grid workloads of `ins-cli bench`: nerf-grid and idr-pretrain.

Plain PyTorch (no tiny-cuda-nn, no extensions), so it runs wherever PyTorch does. Same command
line, timing (one warm-up step, sync, N steps, sync; mean ms) and JSON line as
shared/bench/torch_ref.py:  python torch_grid_ref.py [--threads 2] [--steps 5] [--device cpu|cuda]
[nerf-grid] [idr-pretrain]

Hash encoding (ins-core/src/kernels/hash_grid/kernel.rs): L = 16 levels of F = 2 features,
N_l = floor(N_min * b^l), b = (N_max / N_min)^(1/(L-1)); a level whose (N_l+1)^3 vertices fit the
table T = 2^log2 is stored densely (x + y(N+1) + z(N+1)^2), finer ones hash
(x ^ 2654435761 y ^ 805459861 z) mod T; positions clamped to [0,1], trilinear over 8 corners
(all levels and corners gathered at once here, index_select: its backward is index_add);
table U(-1e-4, 1e-4).

nerf-grid mirrors ins-cli/src/bench/nerf_grid.rs with `train nerf`'s defaults (ins-models/src/nerf):
  scene: 8 views of 64x64 at distance 4 (fov_x 0.691), near 2, far 6, box [-1.5, 1.5]^3;
  occupancy grid 128^3 over the box (step 3/128/2), occupied where a jittered point of the cell
  lies in a ball of radius 0.8, never refreshed; rays marched through it (at most 512 a ray);
  ray count = nearest size bucket of 2^17 / (running mean of samples per ray, starting at 64,
  updated 0.9/0.1 after every step, warm-up included), as NerfTask::ray_count does: with a ball
  of 0.8 a ray holds ~22 samples, so the few bench steps march ~2-2.5k rays, ~50k samples
  (reported as samples_per_step), not yet the 2^17 the running mean converges to;
  field: hash grid (T = 2^17, N 16..1024) -> 64 ReLU -> 1 + 15 (density exp(min(raw, 15)));
  colour: [15 features, SH deg 3 (16)] -> 64 -> 64 ReLU -> 3 sigmoid; NeRF compositing;
  random background behind the alpha (instant-ngp's trick, as ours on masked photos); MSE; Adam
  lr 1e-2 (betas 0.9/0.999, eps 1e-8, fused where PyTorch has it: ours is FusedAdam).
  Differs: targets and alpha are random / the ray hitting the ball, not the synthetic photos;
  marching is tensor ops on the device (all candidate steps at once), ours a loop per ray on
  the host; constant lr (ours decays it over the run: no cost); f32 products (ours uses bf16
  products where the CPU has AVX-512 BF16).

idr-pretrain mirrors ins-cli/src/bench/idr_pretrain.rs with `train idr`'s defaults
(ins-models/src/idr: volume renderer, grid SDF):
  512 rays a step, half drawn inside the mask; cameras at distance 2.6 (400x300, fx 440, fy 448)
  looking at (0, 0, -0.1); mask = the ray meets a ball of radius 0.45 (the synthetic tabletop's
  main sphere); per ray inside the unit sphere: 64 stratified SDF-only samples, 2 rounds of
  up-sampling (16 drawn at sharpness 64, SDF-only, merged; 16 drawn at 128), then 8 strided
  coarse + 16 fine = 24 samples with the SDF's gradient; the colour network at the samples whose
  section weight reaches 1e-4; NeuS section alphas at the learnable s = exp(10 v), v0 = 0.3.
  SDF: hash grid (T = 2^17, N 16..512) over [-1,1]^3, [x, enc] (35) -> 64 softplus(beta 100) ->
  1 + 15, plus |x| - 0.6. Colour: [x, n, dir + sin/cos of 1 octave, 15 features, appearance hash
  grid (T = 2^19, N 16..2047, 32)] (62) -> 128 -> 128 ReLU -> 3 sigmoid.
  Loss: L1 colour over mask rays + 1 x mask BCE (weighted as uniform rays would count) + 0.1 x
  eikonal (every live sample) + 0.1 x curvature (|grad f(x) - grad f(x + 0.01 u)|^2 at <= 2048
  seen samples). Adam lr 5e-3, sharpness x4.
  Differs: the SDF's gradient comes from torch.autograd.grad(create_graph=True) (ours propagates
  forward-mode tangents through the grid's Jacobian and the MLP: same values); random target
  colours; the pinhole ignores the synthetic camera's 0.3 skew and 1.5 px principal-point
  offset; constant lr.

Ours reports the median of the timed steps, this (as torch_ref.py) the mean.
"""
import argparse, json, math, time
import torch
import torch.nn as nn
import torch.nn.functional as F

PRIMES = (1, 2654435761, 805459861)


class HashGrid(nn.Module):
    def __init__(self, log2_table, max_res, levels=16, feats=2, base=16):
        super().__init__()
        t = 1 << log2_table
        growth = (math.log(max_res) - math.log(base)) / (levels - 1)
        res = [max(1, math.floor(base * math.exp(growth * l) + 1e-9)) for l in range(levels)]
        dense = [n + 1 for n in res if (n + 1) ** 3 <= t]  # vertices per axis; coarse levels only
        rows = [v ** 3 for v in dense] + [t] * (levels - len(dense))
        self.table = nn.Parameter(torch.empty(sum(rows), feats).uniform_(-1e-4, 1e-4))
        self.register_buffer("res", torch.tensor(res, dtype=torch.float32)[:, None])
        self.register_buffer("offset", torch.tensor([sum(rows[:l]) for l in range(levels)])[:, None])
        self.register_buffer("dense_scale", torch.tensor([[[1, v, v * v]] for v in dense]))  # [Ld, 1, 3]
        self.register_buffer("primes", torch.tensor(PRIMES))
        self.register_buffer("lo_hi", torch.tensor([[0], [1]]))
        self.n_dense, self.mask, self.d_out = len(dense), t - 1, levels * feats

    def forward(self, x):  # [N, 3] in [0, 1] -> [N, L*F]
        p = x.clamp(0, 1)[:, None, :] * self.res  # [N, L, 3]
        cell = torch.minimum(p.detach().floor(), self.res - 1)
        f = p - cell  # the fraction carries the gradient
        # Per axis the lower and upper vertex, [N, L, 2, 3], combined into the 8 corners
        # [N, L, 8] (corner c = (c & 1, c >> 1 & 1, c >> 2 & 1), as ours).
        corners = lambda a, op: op(op(a[..., None, None, :, 0], a[..., None, :, None, 1]), a[..., :, None, None, 2]).flatten(-3)
        w = corners(torch.stack([1 - f, f], -2), torch.mul)
        i = cell.long()[:, :, None, :] + self.lo_hi
        nd = self.n_dense
        dense = corners(i[:, :nd] * self.dense_scale, torch.add)  # x + y(N+1) + z(N+1)^2
        hashed = corners(i[:, nd:] * self.primes, torch.bitwise_xor) & self.mask
        rows = (torch.cat([dense, hashed], 1) + self.offset).flatten()
        feats = self.table.index_select(0, rows).view(*w.shape, -1)  # backward: index_add
        return (feats * w[..., None]).sum(2).flatten(1)


def sync():
    if torch.cuda.is_available():
        torch.cuda.synchronize()


def bench(fn, steps):
    fn()  # warm-up
    sync()
    t0 = time.perf_counter()
    for _ in range(steps):
        fn()
    sync()
    return (time.perf_counter() - t0) / steps * 1e3


def adam(groups, lr):
    """Adam (0.9, 0.999, 1e-8) in one pass per parameter, as ours (FusedAdam), where PyTorch can."""
    try:
        return torch.optim.Adam(groups, lr, fused=True)
    except (RuntimeError, TypeError):
        return torch.optim.Adam(groups, lr)


def look_at(eye, target):
    f = F.normalize(target - eye, dim=-1)
    right = F.normalize(torch.linalg.cross(f, torch.tensor([0.0, 0.0, 1.0]).expand_as(f)), dim=-1)
    return f, right, torch.linalg.cross(right, f)  # forward, right, up


def pixel_rays(eyes, target, w, h, fx, fy, n):
    """n rays through random pixels of random views: origins and unit directions [n, 3]."""
    fwd, right, up = look_at(eyes, target)
    v = torch.randint(len(eyes), (n,))
    px, py = torch.randint(w, (n,)) + 0.5, torch.randint(h, (n,)) + 0.5
    d = fwd[v] + right[v] * ((px - w / 2) / fx)[:, None] - up[v] * ((py - h / 2) / fy)[:, None]
    return eyes[v], F.normalize(d, dim=-1)


def hits_ball(o, d, r):
    b = (o * d).sum(-1)
    return b * b - (o * o).sum(-1) + r * r > 0


# ---------------------------------------------------------------- nerf-grid

def sh16(d):
    x, y, z = d.unbind(-1)
    xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
    return torch.stack([
        torch.full_like(x, 0.28209479), -0.48860251 * y, 0.48860251 * z, -0.48860251 * x,
        1.0925484 * xy, -1.0925484 * yz, 0.31539157 * (3 * zz - 1), -1.0925484 * xz,
        0.5462742 * (xx - yy), -0.5900436 * y * (3 * xx - yy), 2.8906114 * xy * z,
        -0.4570458 * y * (5 * zz - 1), 0.37317633 * z * (5 * zz - 3), -0.4570458 * x * (5 * zz - 1),
        1.4453057 * z * (xx - yy), -0.5900436 * x * (xx - 3 * yy)], -1)


def nearest_bucket(n):  # ins-core/src/shape_buckets.rs
    if n <= 16:
        return 16
    k = n.bit_length() - 4
    up, down = -(-n // (1 << k)) << k, (n >> k) << k
    return down if n - down <= up - n else up


class GridNerf(nn.Module):
    def __init__(self):
        super().__init__()
        self.grid = HashGrid(17, 1024)
        self.density = nn.Sequential(nn.Linear(32, 64), nn.ReLU(), nn.Linear(64, 16))
        self.color = nn.Sequential(nn.Linear(15 + 16, 64), nn.ReLU(), nn.Linear(64, 64), nn.ReLU(), nn.Linear(64, 3))

    def forward(self, x, sh):  # x in the box [-1.5, 1.5]^3
        out = self.density(self.grid((x + 1.5) / 3.0))
        sigma = out[:, 0].clamp(max=15).exp()
        return sigma, torch.sigmoid(self.color(torch.cat([out[:, 1:], sh], -1)))


def march(o, d, occ, res=128, half=1.5, near=2.0, far=6.0, cap=512):
    """Occupancy-grid marching (ins-core/src/render/occupancy.rs), no gradient: all candidate
    steps of every ray at once, the occupied ones kept. Returns (ray, t) of the kept samples and
    their column in a padded [R, W] layout, and W."""
    step = 2 * half / res * 0.5
    inv = 1.0 / torch.where(d.abs() < 1e-9, torch.full_like(d, 1e-9), d)
    ta, tb = (-half - o) * inv, (half - o) * inv
    t0 = torch.minimum(ta, tb).amax(-1).clamp(min=near)
    t1 = torch.maximum(ta, tb).amin(-1).clamp(max=far)
    k = max(1, int(math.ceil(((t1 - t0).max().item()) / step)) + 1)
    t = t0[:, None] + (torch.rand(len(o), 1) + torch.arange(k)) * step  # [R, K]
    p = o[:, None] + d[:, None] * t[..., None]
    cell = ((p + half) / (2 * half) * res).floor().long()
    inside = ((cell >= 0) & (cell < res)).all(-1)
    cell = cell.clamp(0, res - 1)
    keep = (t < t1[:, None]) & inside & occ[cell[..., 0], cell[..., 1], cell[..., 2]]
    col = keep.cumsum(1) - 1
    keep &= col < cap
    ray, j = keep.nonzero(as_tuple=True)
    return ray, t[ray, j], col[ray, j], int(keep.sum(1).max().item()) if len(ray) else 1


def w_nerf_grid(steps):
    res, step = 128, 3.0 / 128 * 0.5
    c = (torch.stack(torch.meshgrid(*[torch.arange(res)] * 3, indexing="ij"), -1) + torch.rand(res, res, res, 3))
    occ = ((c * (3.0 / res) - 1.5).norm(dim=-1) < 0.8)  # occ[x, y, z]
    i = torch.arange(8.0)
    az, el = i * 2.399963, torch.deg2rad(10 + 50 * ((i + 0.5) / 8 % 1))
    eyes = 4 * torch.stack([el.cos() * az.cos(), el.cos() * az.sin(), el.sin()], -1)
    focal = 32 / math.tan(0.6911112 / 2)
    m = GridNerf(); opt = adam(m.parameters(), 1e-2)
    state = {"spr": 64.0, "rays": [], "samples": [], "loss": None}

    def one():
        r = nearest_bucket(min(max(int(2 ** 17 / max(state["spr"], 1.0)), 256), 1 << 16))
        o, d = pixel_rays(eyes, torch.zeros(3), 64, 64, focal, focal, r)
        with torch.no_grad():
            ray, t, col, width = march(o, d, occ)
        n = len(ray)
        sigma, rgb = m(o[ray] + d[ray] * t[:, None], sh16(d)[ray])
        # Padded [R, W] layout: index into the samples, n (a zero) for padding, as ours.
        index = torch.full((r * width,), n, dtype=torch.long)
        index[ray * width + col] = torch.arange(n)
        delta = torch.zeros(r * width); delta[ray * width + col] = step
        sig = torch.cat([sigma, sigma.new_zeros(1)])[index].view(r, width)
        rgb = torch.cat([rgb, rgb.new_zeros(1, 3)])[index].view(r, width, 3)
        tau = sig * delta.view(r, width)
        w = torch.exp(tau - tau.cumsum(1)) * (1 - torch.exp(-tau))
        opacity = w.sum(1, keepdim=True)
        bg, alpha = torch.rand(r, 3), hits_ball(o, d, 0.8).float()[:, None]
        pred = (w[..., None] * rgb).sum(1) + (1 - opacity) * bg
        target = torch.rand(r, 3) * alpha + (1 - alpha) * bg
        loss = ((pred - target) ** 2).mean()
        opt.zero_grad(); loss.backward(); opt.step()
        state["spr"] = 0.9 * state["spr"] + 0.1 * max(n / r, 1.0)
        state["rays"].append(r); state["samples"].append(n); state["loss"] = loss.detach()

    ms = bench(one, steps)
    rays, samples = state["rays"][1:], state["samples"][1:]  # the timed steps
    return {"ms_per_step": ms, "rays_per_s": sum(rays) / len(rays) / ms * 1e3, "rays": sum(rays) / len(rays),
            "samples_per_step": sum(samples) / len(samples), "samples_per_ray": sum(samples) / sum(rays),
            "grid": "16x2, T=2^17, N=16..1024", "loss": float(state["loss"])}


# ---------------------------------------------------------------- idr-pretrain

class SdfGrid(nn.Module):
    def __init__(self, radius=0.6):
        super().__init__()
        self.grid, self.radius = HashGrid(17, 512), radius
        self.hidden, self.out = nn.Linear(35, 64), nn.Linear(64, 16)
        with torch.no_grad():  # ins-core/src/modules/sdf: N(0, sqrt(2/64)); distance column ~ 0
            self.hidden.weight.normal_(0, math.sqrt(2 / 64)); self.hidden.bias.zero_()
            self.out.weight[0].normal_(0, 1e-4); self.out.bias[0] = 0

    def forward(self, x):  # x in [-1, 1]^3 -> sdf [N], features [N, 15]
        h = F.softplus(self.hidden(torch.cat([x, self.grid(x / 2 + 0.5)], -1)), beta=100)
        out = self.out(h)
        return out[:, 0] + x.norm(dim=-1) - self.radius, out[:, 1:]

    def with_gradient(self, x):
        """sdf, features and grad f, differentiable in the parameters (ours: forward mode)."""
        x = x.detach().requires_grad_(True)
        f, feats = self(x)
        g, = torch.autograd.grad(f.sum(), x, create_graph=True)
        return f, feats, g


class SurfaceColor(nn.Module):
    def __init__(self):
        super().__init__()
        self.grid = HashGrid(19, 2047)
        self.mlp = nn.Sequential(nn.Linear(3 + 3 + 9 + 15 + 32, 128), nn.ReLU(), nn.Linear(128, 128), nn.ReLU(),
                                 nn.Linear(128, 3))

    def forward(self, x, n, d, feats):
        v = torch.cat([d, d.sin(), d.cos()], -1)  # one octave
        return torch.sigmoid(self.mlp(torch.cat([x, n, v, feats, self.grid(x / 2 + 0.5)], -1)))


def end_alpha(f, live, s):  # NeuS section alphas, ins-core/src/render/sdf_volume.rs
    cdf = torch.sigmoid(f * s)
    prev, nxt = cdf[:, :-1], cdf[:, 1:]
    return ((prev - nxt + 1e-5) / (prev + 1e-5)).clamp(0, 1) * live


def alpha_weights(alpha):
    log_clear = torch.log(1 - alpha + 1e-7)
    return alpha * torch.exp(log_clear.cumsum(1) - log_clear)


def draw(t, w, n):  # ins-core/src/render/samplers.rs draw_from_weights, jittered
    mids = 0.5 * (t[:, 1:] + t[:, :-1])
    w = w[:, 1:-1] + 1e-5
    cdf = torch.cat([torch.zeros_like(w[:, :1]), (w / w.sum(1, keepdim=True)).cumsum(1)], 1)
    u = ((torch.arange(n) + torch.rand(len(t), n)) / n).clamp(0, 1 - 1e-6)
    lo = (torch.searchsorted(cdf, u, right=True) - 1).clamp(0, cdf.shape[1] - 2)
    c0, c1 = cdf.gather(1, lo), cdf.gather(1, lo + 1)
    b0, b1 = mids.gather(1, lo), mids.gather(1, lo + 1)
    return b0 + ((u - c0) / (c1 - c0).clamp(min=1e-8)).clamp(0, 1) * (b1 - b0)


def w_idr_pretrain(steps, n_rays=512, coarse=64, kept=8, fine=16, curvature_points=2048):
    i = torch.arange(8.0)
    az, el = torch.deg2rad(-60 + 150 * i / 8), torch.deg2rad(25 + 20 * (i % 3))
    eyes = 2.6 * torch.stack([el.cos() * az.cos(), el.cos() * az.sin(), el.sin()], -1)
    target = torch.tensor([0.0, 0.0, -0.1])
    cam = (eyes, target, 400, 300, 440.0, 448.0)
    o, d = pixel_rays(*cam, 20000)
    frac = hits_ball(o, d, 0.45).float().mean().item()  # the mask's share of the pixels
    sdf, color = SdfGrid(), SurfaceColor()
    variance = nn.Parameter(torch.tensor([0.3]))
    opt = adam([{"params": list(sdf.parameters()) + list(color.parameters())},
                {"params": [variance], "lr": 4 * 5e-3}], 5e-3)
    state = {"seen": [], "loss": None}

    def rays():
        inside = n_rays // 2
        o, d = pixel_rays(*cam, 16 * inside)
        hit = hits_ball(o, d, 0.45)
        o2, d2 = pixel_rays(*cam, n_rays - inside)
        o, d = torch.cat([o[hit][:inside], o2]), torch.cat([d[hit][:inside], d2])
        mask = hits_ball(o, d, 0.45).float()
        weight = 1 / (0.5 + 0.5 / frac * mask)  # uniform density over the one drawn with
        return o, d, mask, weight

    def one():
        o, d, mask, weight = rays()
        b = (o * d).sum(-1); disc = (b * b - (o * o).sum(-1) + 1).clamp(min=0).sqrt()
        live = (disc > 0).float()
        near, far = (-b - disc).clamp(min=0) * live, (-b + disc).clamp(min=0) * live
        along = lambda z: (o[:, None] + d[:, None] * z[..., None]).reshape(-1, 3)
        with torch.no_grad():  # coarse pass and up-sampling: the SDF alone
            z = near[:, None] + (far - near)[:, None] * (torch.arange(coarse) + torch.rand(n_rays, coarse)) / coarse
            f = sdf(along(z))[0].view(n_rays, -1)
            kept_z = z[:, :: coarse // kept]
            for rnd in range(2):
                w = alpha_weights(end_alpha(f, live[:, None], 64.0 * 2 ** rnd))
                drawn = draw(0.5 * (z[:, 1:] + z[:, :-1]), w, fine)
                if rnd == 0:
                    z, order = torch.cat([z, drawn], 1).sort(1)
                    f = torch.cat([f, sdf(along(drawn))[0].view(n_rays, -1)], 1).gather(1, order)
            z = torch.cat([kept_z, drawn], 1).sort(1).values  # [R, 24]
        n = z.shape[1]
        x = along(z)
        f, feats, g = sdf.with_gradient(x)
        s = (10 * variance).clamp(max=13.8).exp()
        w = alpha_weights(end_alpha(f.view(n_rays, n), live[:, None], s))  # [R, n - 1]
        opacity = w.sum(1)
        with torch.no_grad():  # colour only where a section weighs >= 1e-4 (both its ends)
            heavy = w >= 1e-4
            seen = torch.zeros(n_rays, n, dtype=torch.bool)
            seen[:, :-1] |= heavy; seen[:, 1:] |= heavy
            idx = seen.flatten().nonzero()[:, 0]
        xs = x[idx]
        rgb_seen = color(xs, g[idx], d.repeat_interleave(n, 0)[idx], feats[idx])
        rgb = torch.zeros(n_rays * n, 3).index_copy(0, idx, rgb_seen).view(n_rays, n, 3)
        rgb = (w[..., None] * 0.5 * (rgb[:, :-1] + rgb[:, 1:])).sum(1)  # black behind
        target = torch.rand(n_rays, 3)
        l_rgb = ((rgb - target).abs() * mask[:, None]).sum() / mask.sum().clamp(min=1)
        op = opacity.clamp(1e-3, 1 - 1e-3)
        bce = -(mask * op.log() + (1 - mask) * (1 - op).log())
        l_mask = (bce * weight).sum() / weight.sum()
        live_s = live.repeat_interleave(n)
        l_eik = (((g.norm(dim=-1) - 1) ** 2) * live_s).sum() / live_s.sum().clamp(min=1)
        pick = idx[torch.randperm(len(idx))[:curvature_points]]
        u = F.normalize(torch.randn(len(pick), 3), dim=-1)
        g_there = sdf.with_gradient(x.detach()[pick] + 0.01 * u)[2]
        l_curv = ((g[pick] - g_there) ** 2).sum(-1).mean() if len(pick) else 0.0
        loss = l_rgb + 1.0 * l_mask + 0.1 * l_eik + 0.1 * l_curv
        opt.zero_grad(); loss.backward(); opt.step()
        state["seen"].append(len(idx)); state["loss"] = loss.detach()

    ms = bench(one, steps)
    seen = state["seen"][1:]
    return {"ms_per_step": ms, "rays_per_s": n_rays / ms * 1e3, "rays": n_rays,
            "sdf_only_samples_per_ray": coarse + fine, "gradient_samples_per_ray": kept + fine,
            "colour_samples_per_step": sum(seen) / len(seen), "curvature_points": curvature_points,
            "grid": "sdf 16x2 T=2^17 N=16..512; colour 16x2 T=2^19 N=16..2047", "loss": float(state["loss"])}


WORKLOADS = {"nerf-grid": w_nerf_grid, "idr-pretrain": w_idr_pretrain}

if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--device", default="cpu", help="cpu or cuda: where the tensors live")
    ap.add_argument("workloads", nargs="*", default=list(WORKLOADS))
    a = ap.parse_args()
    torch.set_num_threads(a.threads); torch.manual_seed(0)
    torch.set_default_device(a.device)
    for name in a.workloads:
        r = WORKLOADS[name](a.steps)
        print(json.dumps({"workload": name, "engine": "pytorch-" + torch.__version__, "threads": a.threads, "device": a.device, **r}), flush=True)
