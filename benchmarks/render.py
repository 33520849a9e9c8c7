"""Time of a ray-marched preview of the bundled bunny (issue 5).

Fits the bundled example as `jaxrbf reconstruct --example bunny` does (4,000 points, dense, cubic
kernel: 12,000 centres), then renders a 512 x 512 preview with `jaxrbf.render` (default camera:
azimuth 30, elevation 20) twice: cold (with compilation) and warm. The peer, measured in the same
run on the same model and camera, is a naive marcher: fixed steps of 1/256 of the box's diagonal
from where each ray enters the bounding box to the first sign change, then the same bisection and
Newton refinement, jit-compiled on chunks of 4,096 rays. It runs on a smaller image (default
128 x 128) and the two are compared in rays per second. The script reports JAX's default device:
run it on a machine with a GPU (and jax[cuda12]) for the GPU figure.

Targets: a 512 x 512 preview under 20 s on the reference 2-core CPU, under 1 s on a GPU.

Run: python benchmarks/render.py [--size 512] [--peer-size 128] [--png bunny.png] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from _common import ensure_jaxrbf_importable, format_table, machine_info


def naive_render(model, camera, lo, hi, steps_per_diagonal: int = 256):
    """Fixed-step marching to the first sign change, then `_refine`; returns (hit mask, seconds)."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxrbf.render import _CHUNK, _box_entry, _in_chunks, _refine

    step = float(np.linalg.norm(hi - lo)) / steps_per_diagonal

    @eqx.filter_jit
    def march(model, o, d, t, t_far):
        f0 = model(o + t[:, None] * d)

        def cond(s):
            t, _, _, _, done = s
            return ~jnp.all(done)

        def body(s):
            t, tp, fp, _, done = s
            tn = jnp.where(done, t, t + step)
            f = model(o + tn[:, None] * d)
            crossed = ~done & (jnp.sign(f) != jnp.sign(fp))
            out = ~done & (tn > t_far)
            return (
                tn,
                jnp.where(done | crossed, tp, tn),
                jnp.where(done | crossed, fp, f),
                jnp.where(crossed, True, s[3]),
                done | crossed | out,
            )

        init = (t, t, f0, jnp.zeros(t.shape, bool), t > t_far)
        t, tp, fp, hit, _ = jax.lax.while_loop(cond, body, init)
        return t, tp, fp, hit

    start = time.perf_counter()
    o, d = camera.rays()
    t0, t_far, in_box = _box_entry(o, d, lo, hi)
    idx = np.flatnonzero(in_box)
    tb, ta, fa, hit = _in_chunks(
        lambda *a: march(model, *a), [o[idx], d[idx], t0[idx], t_far[idx]], len(idx), _CHUNK
    )
    sel = idx[hit]
    if len(sel):
        fb = np.asarray(model(o[sel] + tb[hit, None] * d[sel]))
        _in_chunks(
            lambda *a: _refine(model, *a, 6, 4),
            [o[sel], d[sel], ta[hit], fa[hit], tb[hit], fb],
            len(sel),
        )
    mask = np.zeros(len(o), bool)
    mask[sel] = True
    return mask.reshape(camera.height, camera.width), time.perf_counter() - start


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=512, help="preview width and height (default 512)")
    ap.add_argument(
        "--peer-size", type=int, default=128, help="image side for the naive marcher (default 128)"
    )
    ap.add_argument("--png", help="save the preview to this PNG")
    ap.add_argument("--json", help="write the figures to this file")
    args = ap.parse_args()

    ensure_jaxrbf_importable()
    import jax
    import numpy as np

    import jaxrbf
    from jaxrbf.render import Camera, render

    info = machine_info()
    device = str(jax.devices()[0])
    print(f"device: {device} ({jax.default_backend()})", file=sys.stderr)

    points, normals = jaxrbf.example("bunny")
    t0 = time.perf_counter()
    model = jaxrbf.fit_surface(points, normals)
    t_fit = time.perf_counter() - t0
    print(f"fit: {len(model.centres):,} centres in {t_fit:.1f} s", file=sys.stderr)

    lo, hi = (np.asarray(b) for b in model.bounds())
    pad = 0.02 * (hi - lo).max()
    lo, hi = lo - pad, hi + pad
    camera = Camera.orbit((lo, hi), 30, 20, size=(args.size, args.size))
    cold = render(model, camera, progress=False)
    warm = render(model, camera, progress=False)
    if args.png:
        warm.save(args.png)
    rays = args.size * args.size
    t_cold, t_warm = cold.stats["seconds"], warm.stats["seconds"]

    small = Camera.orbit((lo, hi), 30, 20, size=(args.peer_size, args.peer_size))
    ours_small = render(model, small, progress=False)
    t_ours_small = render(model, small, progress=False).stats["seconds"]
    naive_render(model, small, lo, hi)  # compile
    naive_hit, t_naive = naive_render(model, small, lo, hi)
    agree = float((naive_hit & ours_small.hit).sum() / max((naive_hit | ours_small.hit).sum(), 1))
    peer_rays = args.peer_size**2

    rows = [
        [
            f"jaxrbf.render {args.size}x{args.size}",
            f"{t_cold:.2f}",
            f"{t_warm:.2f}",
            f"{rays / t_warm:,.0f}",
            f"{warm.stats['evaluations'] / max(warm.stats['box_rays'], 1):.1f}",
        ],
        [
            f"jaxrbf.render {args.peer_size}x{args.peer_size}",
            "",
            f"{t_ours_small:.2f}",
            f"{peer_rays / t_ours_small:,.0f}",
            f"{ours_small.stats['evaluations'] / max(ours_small.stats['box_rays'], 1):.1f}",
        ],
        [
            f"naive fixed-step {args.peer_size}x{args.peer_size}",
            "",
            f"{t_naive:.2f}",
            f"{peer_rays / t_naive:,.0f}",
            "",
        ],
    ]
    print(
        format_table(["what", "cold s", "warm s", "rays/s", "f evals per box ray"], rows),
        flush=True,
    )
    ratio = (rays / t_warm) / (peer_rays / t_naive)
    print(
        f"\n{device}: {args.size}x{args.size} preview in {t_warm:.2f} s warm ({t_cold:.2f} s with "
        f"compilation); {rays / t_warm:,.0f} rays/s, {ratio:.1f}x the naive marcher's rays/s "
        f"(silhouettes agree to IoU {agree:.4f}); hits {warm.stats['hits']:,}, unfinished "
        f"{warm.stats['unfinished']}, unconverged {warm.stats['unconverged']}"
    )
    target = 1.0 if jax.default_backend() == "gpu" else 20.0
    print(f"target: under {target:g} s -> {'met' if t_warm < target else 'NOT met'}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(
                dict(
                    machine=info,
                    device=device,
                    fit_seconds=t_fit,
                    cold=t_cold,
                    warm=t_warm,
                    rays_per_second=rays / t_warm,
                    naive_rays_per_second=peer_rays / t_naive,
                    ratio=ratio,
                    stats=warm.stats,
                ),
                fh,
                indent=2,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
