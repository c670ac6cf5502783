"""How precisely the observation locates the object: can 1 cm (the success radius) be seen in z?

    python -m benchmarks.latent_precision [--encoder PATH] [--objects 5000] [--out outputs/bench_latent.json]

The agents never see object positions, only z = encoder(64x64 mask). This draws objects of Table I at
the task's start/goal poses (EE_home + U[-0.1, 0.1]^2, any yaw), renders their masks, and measures:

- probes: a ridge regression (cubic features) from the 6-number latent to the object's xy, fitted on
  80 % and scored on the rest (error in mm); the same probe from the mask's pixel centroid says what the
  mask itself allows, so the gap is what the encoder loses;
- shifts: each object moved by 2, 5, 10 and 20 mm in a random direction, same size and yaw: how often
  the mask does not change at all, and how far z moves compared with z between two random objects.

If the probe's error is near the success radius, the policy cannot tell "there" from "1 cm away" and
the critic cannot learn where the -1/0 boundary lies from z alone.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import mjx_push  # noqa: F401  (CPU XLA flag)
import jax
import jax.numpy as jnp
import numpy as np
from rich.console import Console
from rich.table import Table

from mjx_push import encoder, masks, objects, scene

SHIFTS_MM = (2.0, 5.0, 10.0, 20.0)


def draw(key: jax.Array, n: int) -> dict:
    """n objects (half boxes, half cylinders) at task poses: sizes, xy, yaw, and a random unit direction."""
    cfg = objects.ObjectConfig()
    home = jnp.asarray(scene.home_flange_pos()[:2], jnp.float32)
    k_shape, k_box, k_cyl, k_xy, k_yaw, k_dir = jax.random.split(key, 6)
    box = jax.vmap(lambda k: objects.sample(k, cfg, "box", home).size)(jax.random.split(k_box, n))
    cyl = jax.vmap(lambda k: objects.sample(k, cfg, "cylinder", home).size)(jax.random.split(k_cyl, n))
    r = cfg.pose_range
    angle = jax.random.uniform(k_dir, (n,), minval=-jnp.pi, maxval=jnp.pi)
    return {"is_box": jax.random.bernoulli(k_shape, 0.5, (n,)), "box": box, "cyl": cyl,
            "xy": home + jax.random.uniform(k_xy, (n, 2), minval=-r, maxval=r),
            "yaw": jax.random.uniform(k_yaw, (n,), minval=-jnp.pi, maxval=jnp.pi),
            "dir": jnp.stack([jnp.cos(angle), jnp.sin(angle)], -1)}


@jax.jit
def render(objs: dict, xy: jax.Array) -> jax.Array:
    def one(is_box, box, cyl, p, yaw):
        b = masks.object_mask("box", box, p, yaw, scene.TABLE_TOP + box[2])
        c = masks.object_mask("cylinder", cyl, p, yaw, scene.TABLE_TOP + cyl[1])
        return jnp.where(is_box, b, c)

    return jax.vmap(one)(objs["is_box"], objs["box"], objs["cyl"], xy, objs["yaw"])


def cubic_features(x: np.ndarray) -> np.ndarray:
    x = (x - x.mean(0)) / (x.std(0) + 1e-9)
    cols = [np.ones(len(x))] + [x[:, i] for i in range(x.shape[1])]
    d = x.shape[1]
    cols += [x[:, i] * x[:, j] for i in range(d) for j in range(i, d)]
    cols += [x[:, i] * x[:, j] * x[:, k] for i in range(d) for j in range(i, d) for k in range(j, d)]
    return np.stack(cols, 1)


def probe(features: np.ndarray, xy: np.ndarray, train_frac: float = 0.8, ridge: float = 1e-3) -> dict:
    """Held-out error (mm) of a ridge regression from cubic features of `features` to xy."""
    f = cubic_features(features.astype(np.float64))
    n = int(train_frac * len(f))
    a = f[:n]
    w = np.linalg.solve(a.T @ a + ridge * np.eye(a.shape[1]), a.T @ xy[:n])
    err = np.linalg.norm(f[n:] @ w - xy[n:], axis=1) * 1000.0
    return {"median_mm": float(np.median(err)), "rmse_mm": float(np.sqrt(np.mean(err**2))),
            "p90_mm": float(np.percentile(err, 90)), "within_10mm": float(np.mean(err < 10.0)),
            "test_objects": int(len(err))}


def measure(encoder_path: Path | None, n: int, seed: int) -> dict:
    params = encoder.load(encoder_path)
    enc = jax.jit(lambda m: encoder.encode(params, m))
    objs = draw(jax.random.PRNGKey(seed), n)
    m0 = render(objs, objs["xy"])
    z0 = np.asarray(enc(m0))
    xy = np.asarray(objs["xy"])
    m0n = np.asarray(m0)
    area = m0n.sum((1, 2))
    grid = np.arange(scene.IMAGE_SIZE) + 0.5
    centroid = np.stack([(m0n.sum(1) * grid).sum(1), (m0n.sum(2) * grid).sum(1)], 1) / np.maximum(area, 1)[:, None]
    rng = np.random.default_rng(seed)
    perm = rng.permutation(n)
    random_pair = np.linalg.norm(z0 - z0[perm], axis=1)
    shifts = []
    for mm in SHIFTS_MM:
        m1 = render(objs, objs["xy"] + objs["dir"] * mm / 1000.0)
        dz = np.linalg.norm(np.asarray(enc(m1)) - z0, axis=1)
        same = np.all(np.asarray(m1) == m0n, axis=(1, 2))
        shifts.append({"shift_mm": mm, "mask_unchanged": float(same.mean()),
                       "pixels_changed_median": float(np.median(np.sum(np.asarray(m1) != m0n, axis=(1, 2)))),
                       "dz_median": float(np.median(dz)),
                       "dz_over_random_pair": float(np.median(dz) / np.median(random_pair))})
    depth = scene.TABLE_TOP - scene.CAMERA_POS[2]
    return {"objects": n, "seed": seed, "pixel_mm_at_table": float(1000 * depth / masks.FOCAL),
            "probe_latent": probe(z0, xy), "probe_mask_centroid": probe(centroid, xy),
            "random_pair_dz_median": float(np.median(random_pair)), "shifts": shifts}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--encoder", type=Path, default=None, help="encoder .msgpack (default: the shipped one)")
    ap.add_argument("--objects", type=int, default=5000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_latent.json"))
    args = ap.parse_args(argv)
    if args.objects < 50:
        ap.error(f"--objects must be >= 50 (the probe holds out 20 %), got {args.objects}")
    t0 = time.perf_counter()
    res = measure(args.encoder, args.objects, args.seed)
    res["wall_s"] = time.perf_counter() - t0
    console = Console()
    console.print(f"mask pixel at the table's height: {res['pixel_mm_at_table']:.1f} mm; "
                  f"{args.objects} objects, {res['probe_latent']['test_objects']} held out")
    t = Table(title="object xy from the observation (held-out error, mm)")
    for c in ("input", "median", "RMSE", "90th pct", "within 10 mm"):
        t.add_column(c, justify="right")
    for name, key in (("latent z (6)", "probe_latent"), ("mask centroid (2)", "probe_mask_centroid")):
        p = res[key]
        t.add_row(name, f"{p['median_mm']:.1f}", f"{p['rmse_mm']:.1f}", f"{p['p90_mm']:.1f}",
                  f"{100 * p['within_10mm']:.0f} %")
    console.print(t)
    t = Table(title=f"object moved, same size and yaw (median |z - z'| of random pairs: {res['random_pair_dz_median']:.3f})")
    for c in ("shift (mm)", "mask unchanged", "pixels changed (median)", "median |dz|", "|dz| / random pair"):
        t.add_column(c, justify="right")
    for s in res["shifts"]:
        t.add_row(f"{s['shift_mm']:.0f}", f"{100 * s['mask_unchanged']:.0f} %", f"{s['pixels_changed_median']:.0f}",
                  f"{s['dz_median']:.4f}", f"{s['dz_over_random_pair']:.3f}")
    console.print(t)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=2) + "\n")
    console.print(f"{res['wall_s']:.0f} s; JSON: {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
