"""A per-pixel affine optic flow fitted between two synthetic frames (``gvnn-warp flow``).

Frame 1 is a procedural multi-scale colour texture (fractal value noise over five octaves,
evaluated analytically); frame 2 is the same texture evaluated at ``p + f(p)`` for a known smooth
non-rigid flow ``f`` (a sum of Gaussian-weighted affine motions), so that
``flow_warp(frame1, f) ~= frame2`` (:func:`make_frames`). A per-pixel affine flow field (``params
(1, 6, H, W)``, initialised to the identity) is fitted with Adam on a robust photometric error
(``robust_rho(affine_flow_warp(frame1, params) - frame2, "cauchy")``) plus a Huber
``smoothness_loss`` on the parameters, coarse to fine (both frames blurred, less and less). The
end-point error (EPE, pixels) against the true flow is printed along the way and compared with the
EPE of the zero flow; :func:`flow_demo` writes ``flow.png`` (:func:`figure`: the frames, both flows
(colour: hue = direction, saturation = magnitude), the warped frame and the residuals).

Example::

    from pathlib import Path
    from gvnn_warp.demos.flow import flow_demo

    stats = flow_demo(Path("out"), size=(64, 48), steps=50)
    print(stats["epe"], stats["epe_zero"])
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from matplotlib.colors import hsv_to_rgb
from matplotlib.figure import Figure

from ..functional import affine_flow, affine_flow_warp, robust_rho, smoothness_loss

__all__ = ["figure", "flow_demo", "make_frames", "save_figure"]


# ----------------------------------------------------------------------------- synthetic data


def _texture(x, y, gen):
    """A colour texture (3, H, W) in about [0, 1] at pixel positions x, y (each (H, W), float64):
    fractal value noise, i.e. random colours on a square lattice, interpolated with the C2 quintic
    smoothstep, summed over 5 octaves of lattice spacing 32, 16, 8, 4, 2 px (each rotated and
    shifted at random) with amplitude ~ spacing^0.8. Evaluated analytically at any position, so
    frame 2 is the texture itself at the moved positions (not a resampled frame 1)."""
    total = torch.zeros(3, *x.shape, dtype=torch.float64)
    norm = 0.0
    margin = 64.0  # the lattice covers positions up to this far outside the image
    for spacing in (32.0, 16.0, 8.0, 4.0, 2.0):
        a = torch.rand(1, generator=gen, dtype=torch.float64).item() * 2 * math.pi
        c, s = math.cos(a), math.sin(a)
        # rotated coordinates (about the image centre), in lattice units, shifted to be >= 0
        cx, cy = x.shape[1] / 2, x.shape[0] / 2
        u = ((x - cx) * c - (y - cy) * s) / spacing
        v = ((x - cx) * s + (y - cy) * c) / spacing
        r = (math.hypot(cx, cy) + margin) / spacing + 1
        u, v = u + r, v + r
        n = int(2 * r) + 3
        lattice = torch.rand(3, n, n, generator=gen, dtype=torch.float64) * 2 - 1
        i0, j0 = u.floor().long().clamp(0, n - 2), v.floor().long().clamp(0, n - 2)
        tu, tv = u - i0, v - j0
        tu = tu**3 * (tu * (tu * 6 - 15) + 10)
        tv = tv**3 * (tv * (tv * 6 - 15) + 10)
        val = (
            lattice[:, j0, i0] * (1 - tu) * (1 - tv)
            + lattice[:, j0, i0 + 1] * tu * (1 - tv)
            + lattice[:, j0 + 1, i0] * (1 - tu) * tv
            + lattice[:, j0 + 1, i0 + 1] * tu * tv
        )
        amp = spacing**0.8
        total += amp * val
        norm += amp
    return total / (1.2 * norm) + 0.5


def _true_flow(H, W, gen):
    """(2, H, W) float64: a sum of 3 Gaussian bumps, each an affine motion about its centre,
    plus a global translation of up to 2 px per axis."""
    y, x = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    flow = torch.zeros(2, H, W, dtype=torch.float64)
    for _ in range(3):
        c = torch.rand(2, generator=gen, dtype=torch.float64) * torch.tensor([W, H]) * 0.6 + torch.tensor([W, H]) * 0.2
        sigma = (0.15 + 0.15 * torch.rand(1, generator=gen, dtype=torch.float64).item()) * min(H, W)
        t = (torch.rand(2, generator=gen, dtype=torch.float64) * 2 - 1) * 5.0
        A = (torch.rand(2, 2, generator=gen, dtype=torch.float64) * 2 - 1) * 0.04
        dx, dy = x - c[0], y - c[1]
        w = torch.exp(-(dx**2 + dy**2) / (2 * sigma**2))
        flow[0] += w * (A[0, 0] * dx + A[0, 1] * dy + t[0])
        flow[1] += w * (A[1, 0] * dx + A[1, 1] * dy + t[1])
    flow += (torch.rand(2, 1, 1, generator=gen, dtype=torch.float64) * 2 - 1) * 2.0
    return flow


def make_frames(W: int, H: int, seed: int):
    """(frame1, frame2, true_flow): (1, 3, H, W), (1, 3, H, W), (1, 2, H, W), float32, with
    frame2(p) = texture(p + flow(p)) and frame1(p) = texture(p)."""
    gen = torch.Generator().manual_seed(seed)
    flow = _true_flow(H, W, gen)
    state = gen.get_state()
    y, x = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    f1 = _texture(x, y, gen)
    gen.set_state(state)  # same texture, displaced
    f2 = _texture(x + flow[0], y + flow[1], gen)
    return f1[None].float(), f2[None].float(), flow[None].float()


def _blur(img, sigma: float):
    if sigma <= 0:
        return img
    r = int(math.ceil(3 * sigma))
    k = torch.exp(-(torch.arange(-r, r + 1, dtype=img.dtype) ** 2) / (2 * sigma**2))
    k = k / k.sum()
    C = img.shape[1]
    out = F.conv2d(F.pad(img, (r, r, 0, 0), mode="replicate"), k.view(1, 1, 1, -1).expand(C, 1, 1, -1), groups=C)
    return F.conv2d(F.pad(out, (0, 0, r, r), mode="replicate"), k.view(1, 1, -1, 1).expand(C, 1, -1, 1), groups=C)


# ----------------------------------------------------------------------------- figure


def _flow_rgb(flow, max_mag: float):
    """(2, H, W) -> (H, W, 3) colours: hue = direction, saturation = magnitude / max_mag."""
    u, v = flow[0], flow[1]
    hue = (np.arctan2(v, u) / (2 * np.pi)) % 1.0
    sat = np.clip(np.hypot(u, v) / max(max_mag, 1e-9), 0, 1)
    return hsv_to_rgb(np.stack([hue, sat, np.ones_like(hue)], -1))


def figure(f1, f2, warped, est, truth, epe_map, stats):
    """The matplotlib figure of ``flow.png`` (see the module docstring); residual and error panels
    carry colour bars with their units."""
    def rgb(t):
        return np.clip(t[0].permute(1, 2, 0).numpy(), 0, 1)

    est_np, truth_np = est[0].numpy(), truth[0].numpy()
    max_mag = float(np.hypot(truth_np[0], truth_np[1]).max())
    res_before = (f2 - f1)[0].abs().mean(0).numpy()
    res_after = (warped - f2)[0].abs().mean(0).numpy()
    vmax = float(res_before.max())
    epe_max = max(float(np.quantile(epe_map, 0.99)), 0.1)  # a few border pixels would dominate
    residual_unit = "|residual|, mean over RGB (intensity, 0-1)"
    residual = dict(cmap="magma", vmin=0, vmax=vmax)

    # a Figure of its own, not pyplot's: no backend chosen, no global state (the caller saves it)
    fig = Figure(figsize=(16, 7), layout="constrained")
    ax = fig.subplots(2, 4)
    panels = [
        (rgb(f1), "frame 1", {}, None),
        (rgb(f2), "frame 2 = frame 1 moved by the true flow", {}, None),
        (rgb(warped), "frame 1 warped by the estimated flow", {}, None),
        (res_after, f"|frame 2 - warped| (mean {res_after.mean():.4f})", residual, residual_unit),
        (_flow_rgb(truth_np, max_mag), f"true flow (max {max_mag:.2f} px)", {}, None),
        (_flow_rgb(est_np, max_mag), "estimated per-pixel affine flow", {}, None),
        (epe_map, f"end-point error (mean {stats['epe']:.3f} px)", dict(cmap="viridis", vmin=0, vmax=epe_max),
         "end-point error, px"),
        (res_before, f"|frame 2 - frame 1| (mean {res_before.mean():.4f})", residual, residual_unit),
    ]
    for a, (img, title, kw, unit) in zip(ax.ravel(), panels, strict=True):
        im = a.imshow(img, **kw)
        a.set_title(title, fontsize=11)
        a.axis("off")
        if unit:
            extend = "max" if kw["cmap"] == "viridis" else "neither"  # the EPE scale is clipped at its 99th percentile
            bar = fig.colorbar(im, ax=a, fraction=0.046, pad=0.02, extend=extend)
            bar.set_label(unit, fontsize=9)
    # colour-wheel key in the corner of the true-flow panel
    n = 41
    gy, gx = np.mgrid[-1 : 1 : n * 1j, -1 : 1 : n * 1j]
    wheel = _flow_rgb(np.stack([gx, gy]), 1.0)
    wheel[np.hypot(gx, gy) > 1] = 1.0
    inset = ax[1, 0].inset_axes([0.0, 0.0, 0.22, 0.3])
    inset.imshow(wheel)
    inset.set_xticks([])
    inset.set_yticks([])
    fig.suptitle(
        f"gvnn-warp flow: per-pixel affine flow fitted in {stats['steps']} Adam steps "
        f"(Cauchy photometric + Huber smoothness); EPE {stats['epe']:.3f} px vs {stats['epe_zero']:.3f} px "
        f"for zero flow\nflow colours: hue = direction, saturation = magnitude (white = 0, full = "
        f"{max_mag:.2f} px; key in the corner)",
        fontsize=12,
    )
    return fig


def save_figure(path: Path, *args) -> None:
    """:func:`figure` of ``args`` written to ``path`` (PNG, 90 dpi)."""
    figure(*args).savefig(path, dpi=90)


# ----------------------------------------------------------------------------- fitting


def flow_demo(out: Path, size: tuple[int, int] = (160, 120), steps: int = 300, seed: int = 0,
              log: Callable[[str], None] = print) -> dict:
    """Make the two frames of ``size`` (width, height) pixels (``seed``: the texture and the true
    flow), fit the per-pixel affine flow in ``steps`` Adam steps (see the module docstring), and
    write ``out/flow.png`` (``out`` is made if missing). Progress lines go to ``log``. Returns
    ``{"epe": mean EPE of the fitted flow, "epe_zero": of the zero flow (px), "steps": steps,
    "median_epe": px, "figure": the figure's path}``.

    Runs on one torch thread (restored after): every torch op here is small and the Warp launches
    are single-threaded, so one thread avoids waking (and, on a busy 2-core machine, waiting for)
    the intra-op pool at each op."""
    t_start = time.perf_counter()
    n_threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _fit(out, size, steps, seed, log, t_start)
    finally:
        torch.set_num_threads(n_threads)


def _fit(out_dir: Path, size: tuple[int, int], steps: int, seed: int, log: Callable[[str], None],
         t_start: float) -> dict:
    W, H = size
    out_dir.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(seed)

    f1, f2, truth = make_frames(W, H, seed)
    epe_zero = truth.norm(dim=1).mean().item()

    # params = identity + q * S: the linear terms move a pixel by x * a, so they are scaled by
    # 1 / s (s ~ half the image size) to give every entry of q a comparable effect in pixels.
    s = 0.5 * max(W, H)
    identity = torch.tensor([1.0, 0, 0, 0, 1, 0], dtype=torch.float32).view(1, 6, 1, 1)
    S = torch.tensor([1 / s, 1 / s, 1.0, 1 / s, 1 / s, 1.0], dtype=torch.float32).view(1, 6, 1, 1)
    q = torch.zeros(1, 6, H, W, dtype=torch.float32, requires_grad=True)
    opt = torch.optim.Adam([q], lr=0.1)
    smooth_weight = 0.02  # photometric: Cauchy, scale 0.1 (intensities in [0, 1]); smoothness: Huber on q
    # coarse to fine: blur sigmas of both frames, and the step at which each stage starts
    sigmas = [4.0, 2.0, 1.0, 0.5]
    bounds = [round(steps * f) for f in (0.0, 0.3, 0.55, 0.8)]
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda i: 1.0 if i < 0.8 * steps else 0.3)

    def params_of(q):
        return identity + q * S

    def epe(params):
        with torch.no_grad():
            return (affine_flow(params) - truth).norm(dim=1)

    log(f"flow: {W}x{H}, {steps} steps, seed {seed}; zero-flow EPE {epe_zero:.3f} px")
    stage = -1
    report_every = max(1, steps // 10)
    for i in range(steps):
        if stage + 1 < len(sigmas) and i >= bounds[stage + 1]:
            while stage + 1 < len(sigmas) and i >= bounds[stage + 1]:
                stage += 1
            src, dst = _blur(f1, sigmas[stage]), _blur(f2, sigmas[stage])
        params = params_of(q)
        warped = affine_flow_warp(src, params, padding_mode="border")
        photo = robust_rho(warped - dst, "cauchy", 0.1).mean()
        smooth = smoothness_loss(q, "huber", 0.05)
        loss = photo + smooth_weight * smooth
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        if i % report_every == 0 or i == steps - 1:
            log(
                f"  step {i + 1:4d}/{steps}  blur {sigmas[stage]:.1f} px  loss {loss.item():.3e}  "
                f"photometric {photo.item():.3e}  smoothness {smooth.item():.3e}  "
                f"EPE {epe(params.detach()).mean().item():.3f} px"
            )

    params = params_of(q).detach()
    epe_map = epe(params)
    final = epe_map.mean().item()
    with torch.no_grad():
        warped = affine_flow_warp(f1, params, padding_mode="border")
        est = affine_flow(params)
    stats = {"epe": final, "epe_zero": epe_zero, "steps": steps}
    fig_path = out_dir / "flow.png"
    save_figure(fig_path, f1, f2, warped, est, truth, epe_map[0].numpy(), stats)
    elapsed = time.perf_counter() - t_start
    median = epe_map.median().item()
    log(
        f"final mean EPE {final:.3f} px (zero flow: {epe_zero:.3f} px, {100 * final / epe_zero:.1f}%); "
        f"median {median:.3f} px; {elapsed:.1f} s; figure {fig_path}"
    )
    return {**stats, "median_epe": median, "figure": fig_path}
