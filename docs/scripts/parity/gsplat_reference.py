#!/usr/bin/env python3
"""An independent 3D Gaussian splatting trainer written from gsplat 1.5.3's published maths
(classic projection and rasterisation, DefaultStrategy densification, simple_trainer's
defaults), in PyTorch on the CPU with autograd for the gradients. It shares no code with
augsplat: its only use is to record what "plain gsplat" reaches on a small fixed case, so that
`tests/gsplat_parity.rs` can catch a drift of augsplat's baseline away from it.

    python3 gsplat_reference.py TRAIN_SCENE_DIR TEST_SCENE_DIR --steps 1000 --seed 0 \
        --out curve.json

TRAIN_SCENE_DIR / TEST_SCENE_DIR are augsplat scene folders (`scene.json`, `images/`,
`points.safetensors` in the training one), e.g. the outputs of the `split` node.

What it follows (gsplat 1.5.3, `simple_trainer.py` with its default `DefaultStrategy`):
- init from the SfM points: colour → SH DC, isotropic log-scale of the RMS distance to the 3
  nearest neighbours, quaternions uniform in [0, 1)^4 (normalised), opacity 0.1;
- Adam (β 0.9 / 0.999, ε 1e-15), rates: means 1.6e-4 × scene scale decaying to 0.01× over
  the run, log-scales 5e-3, quaternions 1e-3, opacity logits 5e-2, SH DC 2.5e-3, SH rest
  2.5e-3 / 20; the scene scale is 1.1 × the largest camera distance from the cameras' mean;
- one training view per step, epochs in shuffled order; SH degree + 1 every 1000 steps;
- loss 0.8 · L1 + 0.2 · (1 − SSIM) (11 × 11 Gaussian window σ 1.5, "valid" padding);
- projection: EWA with the Jacobian's x/z, y/z clamped to 1.3 × the half field of view,
  a 0.3 px² blur, near plane 0.01, radius ceil(3·sqrt(λ_max)) with λ_max from
  b + sqrt(max(0.01, b² − det)), culled when det ≤ 0, radius ≤ 0 or off-screen;
- rasterisation in 16 × 16 tiles, Gaussians of a tile sorted by depth, pixel centres at +0.5,
  α = min(0.999, o·exp(−σ)) (gsplat 1.5.x's clamp), skipped when σ < 0 or α < 1/255, a pixel
  stops before the Gaussian that takes its transmittance to ≤ 1e-4; black background;
- densification: the view's screen-space gradient of the projected means, scaled by
  (W/2, H/2), summed with a count for every Gaussian of non-zero radius; at steps
  `> start`, `% every == 0`, `< stop`: clone (grad > 2e-4 and max scale ≤ 0.01 × scene scale),
  split the other high-gradient ones into two children drawn from the Gaussian with scales
  / 1.6, prune opacity < 0.005 (and max scale > 0.1 × scene scale after `reset_every`
  steps), clear the statistics; no opacity reset (1.5.3's condition is never true). The
  schedule (start, stop, every, reset_every) is given on the command line, so the same scaled
  schedule as augsplat's can be used.
"""

import argparse
import json
import math
import os
import struct
import time

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

TILE = 16
C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = [1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
      0.5462742152960396]
C3 = [-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
      -0.4570457994644658, 1.445305721320277, -0.5900435899266435]


def read_safetensors(path):
    with open(path, "rb") as f:
        raw = f.read()
    n = struct.unpack("<Q", raw[:8])[0]
    header = json.loads(raw[8:8 + n])
    out = {}
    dt = {"F32": np.float32, "U32": np.uint32, "F64": np.float64, "U8": np.uint8}
    for name, t in header.items():
        if name == "__metadata__":
            continue
        a, b = t["data_offsets"]
        out[name] = np.frombuffer(raw[8 + n + a:8 + n + b], dtype=dt[t["dtype"]]).reshape(t["shape"])
    return out


def load_scene(folder):
    with open(os.path.join(folder, "scene.json")) as f:
        scene = json.load(f)
    views = []
    for v in scene["views"]:
        img = np.asarray(Image.open(os.path.join(folder, v["image"])).convert("RGB"),
                         dtype=np.float32) / 255.0
        c = v["camera"]
        views.append({
            "name": v["name"],
            "image": torch.from_numpy(img),
            "w2c": torch.tensor(c["world_to_camera"], dtype=torch.float64),
            "fx": c["fx"], "fy": c["fy"], "cx": c["cx"], "cy": c["cy"],
            "width": c["width"], "height": c["height"],
        })
    return views


def quat_to_rot(q):
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(q.shape[:-1] + (3, 3))


def sh_colour(degree, dirs, sh0, shn):
    """gsplat's `spherical_harmonics` (real SH, the 3DGS constants) plus 0.5, clamped at 0."""
    out = C0 * sh0[:, 0]
    if degree > 0:
        d = dirs / dirs.norm(dim=-1, keepdim=True)
        x, y, z = d[:, 0:1], d[:, 1:2], d[:, 2:3]
        out = out - C1 * y * shn[:, 0] + C1 * z * shn[:, 1] - C1 * x * shn[:, 2]
        if degree > 1:
            xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
            out = (out + C2[0] * xy * shn[:, 3] + C2[1] * yz * shn[:, 4]
                   + C2[2] * (2 * zz - xx - yy) * shn[:, 5] + C2[3] * xz * shn[:, 6]
                   + C2[4] * (xx - yy) * shn[:, 7])
            if degree > 2:
                out = (out + C3[0] * y * (3 * xx - yy) * shn[:, 8] + C3[1] * xy * z * shn[:, 9]
                       + C3[2] * y * (4 * zz - xx - yy) * shn[:, 10]
                       + C3[3] * z * (2 * zz - 3 * xx - 3 * yy) * shn[:, 11]
                       + C3[4] * x * (4 * zz - xx - yy) * shn[:, 12]
                       + C3[5] * z * (xx - yy) * shn[:, 13]
                       + C3[6] * x * (xx - 3 * yy) * shn[:, 14])
    return torch.clamp_min(out + 0.5, 0.0)


def render(splats, view, sh_degree, max_alpha=0.999):
    """Returns (image H×W×3, means2d (N×2, retains its grad), radii (N))."""
    w2c = view["w2c"].float()
    R, t = w2c[:3, :3], w2c[:3, 3]
    W, H = view["width"], view["height"]
    fx, fy, cx, cy = view["fx"], view["fy"], view["cx"], view["cy"]
    means = splats["means"]
    pc = means @ R.T + t
    x, y, z = pc.unbind(-1)
    zs = torch.where(z > 0.01, z, torch.ones_like(z))
    tan_x, tan_y = 0.5 * W / fx, 0.5 * H / fy
    lx_pos, lx_neg = (W - cx) / fx + 0.3 * tan_x, cx / fx + 0.3 * tan_x
    ly_pos, ly_neg = (H - cy) / fy + 0.3 * tan_y, cy / fy + 0.3 * tan_y
    tx = zs * torch.clamp(x / zs, -lx_neg, lx_pos)
    ty = zs * torch.clamp(y / zs, -ly_neg, ly_pos)
    zero = torch.zeros_like(zs)
    J = torch.stack([
        torch.stack([fx / zs, zero, -fx * tx / (zs * zs)], -1),
        torch.stack([zero, fy / zs, -fy * ty / (zs * zs)], -1),
    ], -2)
    rot = quat_to_rot(splats["quats"])
    s = torch.exp(splats["scales"])
    M = rot * s[:, None, :]
    cov3 = M @ M.transpose(1, 2)
    T = J @ R[None]
    cov2 = T @ cov3 @ T.transpose(1, 2)
    a = cov2[:, 0, 0] + 0.3
    b = cov2[:, 0, 1]
    c = cov2[:, 1, 1] + 0.3
    det = a * c - b * b
    dets = torch.where(det > 0, det, torch.ones_like(det))
    conic = torch.stack([c / dets, -b / dets, a / dets], -1)
    mean2d = torch.stack([fx * x / zs + cx, fy * y / zs + cy], -1)
    if mean2d.requires_grad:
        mean2d.retain_grad()
    with torch.no_grad():
        bb = 0.5 * (a + c)
        v1 = bb + torch.sqrt(torch.clamp_min(bb * bb - det, 0.01))
        radius = torch.ceil(3.0 * torch.sqrt(v1))
        ok = (z > 0.01) & (det > 0) & (radius > 0)
        mx, my = mean2d[:, 0], mean2d[:, 1]
        ok &= ~((mx + radius <= 0) | (mx - radius >= W) | (my + radius <= 0) | (my - radius >= H))
        radii = torch.where(ok, radius, torch.zeros_like(radius))
    campos = -R.T @ t
    colour = sh_colour(sh_degree, means - campos, splats["sh0"], splats["shN"])
    opac = torch.sigmoid(splats["opacities"])

    # Tiles: each Gaussian's tile rectangle, each tile's Gaussians by depth.
    tw, th = (W + TILE - 1) // TILE, (H + TILE - 1) // TILE
    with torch.no_grad():
        vis = torch.nonzero(radii > 0).squeeze(-1)
        txc, tyc, tr = mx[vis] / TILE, my[vis] / TILE, radii[vis] / TILE
        x0 = torch.clamp(torch.floor(txc - tr), 0, tw).long()
        x1 = torch.clamp(torch.ceil(txc + tr), 0, tw).long()
        y0 = torch.clamp(torch.floor(tyc - tr), 0, th).long()
        y1 = torch.clamp(torch.ceil(tyc + tr), 0, th).long()
        order = torch.argsort(z[vis], stable=True)
        vis, x0, x1, y0, y1 = vis[order], x0[order], x1[order], y0[order], y1[order]
        lists = []
        for ty_ in range(th):
            for tx_ in range(tw):
                m = (x0 <= tx_) & (tx_ < x1) & (y0 <= ty_) & (ty_ < y1)
                lists.append(vis[m])
        K = max(1, max(len(l) for l in lists))
        n = means.shape[0]
        idx = torch.full((len(lists), K), n, dtype=torch.long)
        for i, l in enumerate(lists):
            idx[i, :len(l)] = l
        ys, xs = torch.meshgrid(torch.arange(TILE), torch.arange(TILE), indexing="ij")
        tiles_y = torch.arange(th).repeat_interleave(tw)
        tiles_x = torch.arange(tw).repeat(th)
        px = (tiles_x[:, None] * TILE + xs.reshape(-1)[None]).float()
        py = (tiles_y[:, None] * TILE + ys.reshape(-1)[None]).float()
    pad = lambda v: torch.cat([v, torch.zeros((1,) + v.shape[1:], dtype=v.dtype)], 0)
    m2, cn, op, col = pad(mean2d)[idx], pad(conic)[idx], pad(opac)[idx], pad(colour)[idx]
    dx = m2[:, None, :, 0] - (px[:, :, None] + 0.5)
    dy = m2[:, None, :, 1] - (py[:, :, None] + 0.5)
    sigma = 0.5 * (cn[:, None, :, 0] * dx * dx + cn[:, None, :, 2] * dy * dy) + cn[:, None, :, 1] * dx * dy
    alpha = torch.clamp_max(op[:, None, :] * torch.exp(-sigma), max_alpha)
    valid = (sigma >= 0) & (alpha >= 1.0 / 255.0) & (idx < n)[:, None, :]
    alpha = torch.where(valid, alpha, torch.zeros_like(alpha))
    with torch.no_grad():
        keep = torch.cumprod(1 - alpha, -1) > 1e-4
    alpha = alpha * keep
    trans = torch.cumprod(1 - alpha, -1)
    trans = torch.cat([torch.ones_like(trans[..., :1]), trans[..., :-1]], -1)
    wgt = alpha * trans
    rgb = torch.einsum("tpk,tkc->tpc", wgt, col)
    img = rgb.reshape(th, tw, TILE, TILE, 3).permute(0, 2, 1, 3, 4).reshape(th * TILE, tw * TILE, 3)
    return img[:H, :W], mean2d, radii


def ssim(a, b):
    """Mean SSIM of two H×W×3 images, 11×11 Gaussian window (σ 1.5), valid padding."""
    g = torch.exp(-((torch.arange(11) - 5.0) ** 2) / (2 * 1.5 ** 2))
    g = g / g.sum()
    win = (g[:, None] * g[None, :]).expand(3, 1, 11, 11)
    x, y = a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None]
    f = lambda v: F.conv2d(v, win, groups=3)
    mx, my = f(x), f(y)
    sxx, syy, sxy = f(x * x) - mx * mx, f(y * y) - my * my, f(x * y) - mx * my
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    m = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return m.mean()


def knn_rms(points, k=3):
    d2 = torch.cdist(points, points) ** 2
    d2.fill_diagonal_(float("inf"))
    return torch.sqrt(torch.topk(d2, k, largest=False).values.mean(-1))


def scene_scale(views):
    centres = torch.stack([-(v["w2c"][:3, :3].T @ v["w2c"][:3, 3]) for v in views])
    return 1.1 * float((centres - centres.mean(0)).norm(dim=-1).max())


class Adam:
    def __init__(self, lr, betas=(0.9, 0.999), eps=1e-15):
        self.lr, self.b1, self.b2, self.eps = lr, betas[0], betas[1], eps
        self.m = self.v = None
        self.t = 0

    def step(self, p, g):
        if self.m is None:
            self.m, self.v = torch.zeros_like(p), torch.zeros_like(p)
        self.t += 1
        self.m.mul_(self.b1).add_(g, alpha=1 - self.b1)
        self.v.mul_(self.b2).addcmul_(g, g, value=1 - self.b2)
        mh = self.m / (1 - self.b1 ** self.t)
        vh = self.v / (1 - self.b2 ** self.t)
        p.sub_(self.lr * mh / (vh.sqrt() + self.eps))

    def edit(self, keep, new_rows):
        """Keeps the rows `keep` of the moments and appends `new_rows` zero rows."""
        if self.m is None:
            return
        z = torch.zeros((new_rows,) + self.m.shape[1:])
        self.m = torch.cat([self.m[keep], z])
        self.v = torch.cat([self.v[keep], z])


def train(args):
    torch.manual_seed(args.seed)
    gen = np.random.default_rng(args.seed)
    train_views, test_views = load_scene(args.train), load_scene(args.test)
    pts = read_safetensors(os.path.join(args.train, "points.safetensors"))
    points = torch.from_numpy(pts["positions"].copy()).float()
    rgb = torch.from_numpy(pts["colors"].copy()).float()
    n = points.shape[0]
    sscale = scene_scale(train_views)
    splats = {
        "means": points.clone(),
        "scales": torch.log(knn_rms(points)).unsqueeze(-1).repeat(1, 3),
        "quats": torch.rand((n, 4)),
        "opacities": torch.logit(torch.full((n,), 0.1)),
        "sh0": ((rgb - 0.5) / C0).unsqueeze(1),
        "shN": torch.zeros((n, 15, 3)),
    }
    lrs = {"means": 1.6e-4 * sscale, "scales": 5e-3, "quats": 1e-3, "opacities": 5e-2,
           "sh0": 2.5e-3, "shN": 2.5e-3 / 20}
    opt = {k: Adam(v) for k, v in lrs.items()}
    decay = 0.01 ** (1.0 / args.steps)
    grad2d = torch.zeros(n)
    count = torch.zeros(n)
    order = []
    curve = []
    t0 = time.time()

    def evaluate(step):
        deg = min(step // args.sh_every, 3)
        with torch.no_grad():
            ps = []
            for v in test_views:
                img, _, _ = render({k: p for k, p in splats.items()}, v, deg)
                mse = ((img.clamp(0, 1) - v["image"]) ** 2).mean().item()
                ps.append(10 * math.log10(1.0 / max(mse, 1e-20)))
        curve.append({"step": step, "psnr": sum(ps) / len(ps), "gaussians": splats["means"].shape[0]})
        print(f"seed {args.seed} step {step}: held-out PSNR {curve[-1]['psnr']:.3f} dB, "
              f"{splats['means'].shape[0]} Gaussians, {time.time() - t0:.0f} s", flush=True)

    for step in range(args.steps):
        if not order:
            order = list(gen.permutation(len(train_views)))
        v = train_views[order.pop(0)]
        for p in splats.values():
            p.requires_grad_(True)
            p.grad = None
        deg = min(step // args.sh_every, 3)
        img, mean2d, radii = render(splats, v, deg)
        gt = v["image"]
        loss = 0.8 * (img - gt).abs().mean() + 0.2 * (1 - ssim(img, gt))
        loss.backward()
        with torch.no_grad():
            for k, p in splats.items():
                # Unused SH bands get a zero gradient (gsplat passes all coefficients).
                opt[k].step(p, p.grad if p.grad is not None else torch.zeros_like(p))
                p.requires_grad_(False)
            opt["means"].lr *= decay
            if step < args.stop:
                g = mean2d.grad.clone()
                g[:, 0] *= v["width"] / 2.0
                g[:, 1] *= v["height"] / 2.0
                sel = radii > 0
                grad2d[sel] += g[sel].norm(dim=-1)
                count[sel] += 1
                if step > args.start and step % args.every == 0:
                    splats, grad2d, count = refine(splats, opt, grad2d, count, sscale, step, args)
        if (step + 1) % args.eval_every == 0:
            evaluate(step + 1)
    return {"seed": args.seed, "steps": args.steps, "scene_scale": sscale, "curve": curve,
            "seconds": time.time() - t0}


def refine(splats, opt, grad2d, count, sscale, step, args):
    n = splats["means"].shape[0]
    avg = grad2d / count.clamp_min(1)
    high = avg > 2e-4
    small = torch.exp(splats["scales"]).max(-1).values <= 0.01 * sscale
    dup = high & small
    # Clone: append copies, with zero moments as gsplat's `duplicate`.
    keep = torch.arange(n)
    for k in splats:
        splats[k] = torch.cat([splats[k], splats[k][dup]])
        opt[k].edit(keep, int(dup.sum()))
    split = torch.cat([high & ~small, torch.zeros(int(dup.sum()), dtype=torch.bool)])
    # Split: two children drawn from each, originals removed.
    s = torch.exp(splats["scales"][split])
    rot = quat_to_rot(splats["quats"][split])
    noise = torch.randn(2, s.shape[0], 3)
    samples = torch.einsum("nij,nj,bnj->bni", rot, s, noise)
    rest = torch.nonzero(~split).squeeze(-1)
    children = {
        "means": (splats["means"][split] + samples).reshape(-1, 3),
        "scales": torch.log(s / 1.6).repeat(2, 1),
    }
    for k in splats:
        new = children.get(k, splats[k][split].repeat((2,) + (1,) * (splats[k].dim() - 1)))
        splats[k] = torch.cat([splats[k][rest], new])
        opt[k].edit(rest, new.shape[0])
    # Prune.
    prune = torch.sigmoid(splats["opacities"]) < 0.005
    if step > args.reset_every:
        prune |= torch.exp(splats["scales"]).max(-1).values > 0.1 * sscale
    alive = torch.nonzero(~prune).squeeze(-1)
    for k in splats:
        splats[k] = splats[k][alive]
        opt[k].edit(alive, 0)
    m = splats["means"].shape[0]
    return splats, torch.zeros(m), torch.zeros(m)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("train")
    ap.add_argument("test")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--eval-every", type=int, default=100)
    ap.add_argument("--sh-every", type=int, default=1000)
    ap.add_argument("--start", type=int, required=True)
    ap.add_argument("--stop", type=int, required=True)
    ap.add_argument("--every", type=int, required=True)
    ap.add_argument("--reset-every", type=int, required=True)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    result = train(args)
    with open(args.out, "w") as f:
        json.dump(result, f, indent=1)


if __name__ == "__main__":
    main()
