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

Per shape, since learners are far less precise on cuboids than on cylinders: the xy probe on each
shape alone, and for cuboids what pushing them needs beyond the centre: the yaw of the faces (mod
90 degrees: a probe of (cos 4 yaw, sin 4 yaw)), the yaw of the long side of rectangular cuboids (mod
180: cos/sin 2 yaw, for cuboids whose sides differ by at least 2 cm), and the footprint (length and
width, the larger first).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from mjx_push import xla  # the CPU fusion-emitter flag on import (before jax)
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
    return {
        "is_box": jax.random.bernoulli(k_shape, 0.5, (n,)),
        "box": box,
        "cyl": cyl,
        "xy": home + jax.random.uniform(k_xy, (n, 2), minval=-r, maxval=r),
        "yaw": jax.random.uniform(k_yaw, (n,), minval=-jnp.pi, maxval=jnp.pi),
        "dir": jnp.stack([jnp.cos(angle), jnp.sin(angle)], -1),
    }


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


def fit(features: np.ndarray, target: np.ndarray, train_frac: float = 0.8, ridge: float = 1e-3):
    """(held-out predictions, held-out targets) of a ridge regression from cubic features."""
    f = cubic_features(features.astype(np.float64))
    n = int(train_frac * len(f))
    a = f[:n]
    w = np.linalg.solve(a.T @ a + ridge * np.eye(a.shape[1]), a.T @ target[:n])
    return f[n:] @ w, target[n:]


def probe(features: np.ndarray, xy: np.ndarray, train_frac: float = 0.8, ridge: float = 1e-3) -> dict:
    """Held-out error (mm) of a ridge regression from cubic features of `features` to xy."""
    pred, want = fit(features, xy, train_frac, ridge)
    err = np.linalg.norm(pred - want, axis=1) * 1000.0
    return {
        "median_mm": float(np.median(err)),
        "rmse_mm": float(np.sqrt(np.mean(err**2))),
        "p90_mm": float(np.percentile(err, 90)),
        "within_10mm": float(np.mean(err < 10.0)),
        "test_objects": int(len(err)),
    }


def knn(features: np.ndarray, target: np.ndarray, k: int = 10, train_frac: float = 0.8):
    """(held-out predictions, held-out targets) of a k-nearest-neighbour regression on standardised
    features: a probe that assumes nothing about how the features encode the target."""
    f = ((features - features.mean(0)) / (features.std(0) + 1e-9)).astype(np.float32)
    n = int(train_frac * len(f))
    a, b = f[n:], f[:n]  # squared distances without an [n_test, n_train, dim] array (masks: 4,096 dims)
    d = (a * a).sum(1)[:, None] + (b * b).sum(1)[None] - 2.0 * a @ b.T
    return target[:n][np.argsort(d, 1)[:, :k]].mean(1), target[n:]


def probe_angle(features: np.ndarray, yaw: np.ndarray, k: int, pixels: np.ndarray | None = None) -> dict:
    """Held-out error (degrees) of the yaw modulo 360/k, probed as (cos k yaw, sin k yaw) by the cubic
    ridge probe and by k nearest neighbours. A yaw uniform over the period and a probe that knows
    nothing give a median error of a quarter of the period."""
    target = np.stack([np.cos(k * yaw), np.sin(k * yaw)], 1)
    out = {"period_deg": 360.0 / k, "chance_median_deg": 90.0 / k}
    probes = [("ridge", fit(features, target)), ("knn", knn(features, target))]
    if pixels is not None:  # the mask itself, by nearest neighbours: what any encoder could pass on
        probes.append(("mask_knn", knn(pixels, target)))
    for name, (pred, want) in probes:
        got, true = np.arctan2(pred[:, 1], pred[:, 0]), np.arctan2(want[:, 1], want[:, 0])
        err = np.degrees(np.abs(np.angle(np.exp(1j * (got - true))))) / k
        out.update({f"{name}_median_deg": float(np.median(err)), f"{name}_p90_deg": float(np.percentile(err, 90))})
    out["test_objects"] = int(len(err))
    return out


def probe_size(features: np.ndarray, sides: np.ndarray) -> dict:
    """Held-out error (mm) of the footprint's (larger, smaller) side."""
    pred, want = fit(features, sides)
    err = np.abs(pred - want) * 1000.0
    return {
        "median_mm_long": float(np.median(err[:, 0])),
        "median_mm_short": float(np.median(err[:, 1])),
        "test_objects": int(len(err)),
    }


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
        shifts.append(
            {
                "shift_mm": mm,
                "mask_unchanged": float(same.mean()),
                "pixels_changed_median": float(np.median(np.sum(np.asarray(m1) != m0n, axis=(1, 2)))),
                "dz_median": float(np.median(dz)),
                "dz_over_random_pair": float(np.median(dz) / np.median(random_pair)),
            }
        )
    depth = scene.TABLE_TOP - scene.CAMERA_POS[2]
    is_box = np.asarray(objs["is_box"])
    yaw = np.asarray(objs["yaw"])
    sides = 2.0 * np.sort(np.asarray(objs["box"])[:, :2], axis=1)[:, ::-1]  # full (long, short) footprint
    rect = is_box & (sides[:, 0] - sides[:, 1] >= objects.RECT_MIN_DIFF)
    per_shape = {
        name: {"probe_latent": probe(z0[sel], xy[sel]), "probe_mask_centroid": probe(centroid[sel], xy[sel])}
        for name, sel in (("cuboid", is_box), ("cylinder", ~is_box))
    }
    pixels = m0n.reshape(n, -1).astype(np.float32)
    cuboid = {
        "face_yaw_mod_90": probe_angle(z0[is_box], yaw[is_box], 4, pixels[is_box]),
        "long_side_yaw_mod_180": probe_angle(z0[rect], yaw[rect], 2, pixels[rect]),
        "footprint": probe_size(z0[is_box], sides[is_box]),
    }
    return {
        "objects": n,
        "seed": seed,
        "pixel_mm_at_table": float(1000 * depth / masks.FOCAL),
        "probe_latent": probe(z0, xy),
        "probe_mask_centroid": probe(centroid, xy),
        "per_shape": per_shape,
        "cuboid_pose": cuboid,
        "random_pair_dz_median": float(np.median(random_pair)),
        "shifts": shifts,
    }


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
    console.print(
        f"mask pixel at the table's height: {res['pixel_mm_at_table']:.1f} mm; "
        f"{args.objects} objects, {res['probe_latent']['test_objects']} held out"
    )
    t = Table(title="object xy from the observation (held-out error, mm)")
    for c in ("input", "median", "RMSE", "90th pct", "within 10 mm"):
        t.add_column(c, justify="right")
    rows = [("latent z (6)", res["probe_latent"]), ("mask centroid (2)", res["probe_mask_centroid"])]
    for shape, d in res["per_shape"].items():
        rows += [(f"{shape}s: latent z", d["probe_latent"]), (f"{shape}s: mask centroid", d["probe_mask_centroid"])]
    for name, p in rows:
        t.add_row(
            name,
            f"{p['median_mm']:.1f}",
            f"{p['rmse_mm']:.1f}",
            f"{p['p90_mm']:.1f}",
            f"{100 * p['within_10mm']:.0f} %",
        )
    console.print(t)
    c = res["cuboid_pose"]
    t = Table(title="what pushing a cuboid needs beyond its centre, from z (held-out error)")
    for col in (
        "quantity",
        "median (ridge)",
        "90th pct (ridge)",
        "median (10-NN)",
        "mask pixels (10-NN)",
        "chance median",
    ):
        t.add_column(col, justify="right")
    for name, key in (
        ("face yaw (mod 90 deg)", "face_yaw_mod_90"),
        ("long side yaw (mod 180 deg)", "long_side_yaw_mod_180"),
    ):
        a = c[key]
        t.add_row(
            name,
            f"{a['ridge_median_deg']:.1f} deg",
            f"{a['ridge_p90_deg']:.1f} deg",
            f"{a['knn_median_deg']:.1f} deg",
            f"{a['mask_knn_median_deg']:.1f} deg",
            f"{a['chance_median_deg']:.1f} deg",
        )
    t.add_row(
        "footprint long / short side",
        f"{c['footprint']['median_mm_long']:.1f} / {c['footprint']['median_mm_short']:.1f} mm",
        "",
        "",
        "",
        "",
    )
    console.print(t)
    t = Table(
        title=f"object moved, same size and yaw (median |z - z'| of random pairs: {res['random_pair_dz_median']:.3f})"
    )
    for c in ("shift (mm)", "mask unchanged", "pixels changed (median)", "median |dz|", "|dz| / random pair"):
        t.add_column(c, justify="right")
    for s in res["shifts"]:
        t.add_row(
            f"{s['shift_mm']:.0f}",
            f"{100 * s['mask_unchanged']:.0f} %",
            f"{s['pixels_changed_median']:.0f}",
            f"{s['dz_median']:.4f}",
            f"{s['dz_over_random_pair']:.3f}",
        )
    console.print(t)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=2) + "\n")
    console.print(f"{res['wall_s']:.0f} s; JSON: {args.out}")
    return 0


if __name__ == "__main__":
    xla.use_cpu_devices()  # one CPU device per core, as the mjx-push command does
    raise SystemExit(main())
