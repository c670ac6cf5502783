"""The rendered camera masks against the analytic projection MJX trains with, pixel by pixel.

    MUJOCO_GL=egl python -m benchmarks.mask_gap [--poses 150] [--seed 5] [--out outputs/bench_mask_gap.json]

For each shape, `--poses` objects of Table I at their start poses (drawn as the environment draws
them), each masked twice in CPU MuJoCo: rendered by the under-table camera and colour-filtered (as the
real camera's pipeline), and by the analytic projection (`mjx_push.mask_geometry`, with NumPy). Reports the mean pixel
counts seen only by the render and only by the projection (a systematic gap shows as one side larger),
the IoU (mean, min) and the shift of the mask's centroid (pixels). Prints a table, writes JSON.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from mjx_push import xla  # the CPU fusion-emitter flag on import (before jax)
import numpy as np


def gap(rendered: np.ndarray, analytic: np.ndarray) -> dict:
    """One pose's masks (bool [n, n]): pixels only rendered, only analytic, IoU, centroid shift (rows, cols)."""
    r, a = np.asarray(rendered, bool), np.asarray(analytic, bool)
    if r.shape != a.shape or not a.any() or not r.any():
        raise ValueError(
            f"two non-empty masks of one shape are needed, got {r.shape} ({r.sum()}) and {a.shape} ({a.sum()})"
        )
    return {
        "render_only": int((r & ~a).sum()),
        "analytic_only": int((a & ~r).sum()),
        "analytic_pixels": int(a.sum()),
        "iou": float((r & a).sum() / (r | a).sum()),
        "centroid_shift": (np.argwhere(r).mean(0) - np.argwhere(a).mean(0)).tolist(),
    }


def measure(shape: str, poses: int, seed: int) -> dict:
    from mjx_push import mask_geometry
    from mjx_push.export.cpu_env import CpuPushEnv, sample_params
    from mjx_push import objects

    env = CpuPushEnv(geom_type=shape, mask_source="render")
    cfg = objects.ObjectConfig(shape="any")
    rows = []
    for i in range(poses):
        obs = env.reset(params=sample_params(seed + i, cfg, shape))
        info = env.info()
        ana = mask_geometry.object_mask(shape, env.params.size, info["object_xy"], info["object_yaw"], info["object_z"])
        rows.append(gap(obs["object_mask"], ana))
    env.close()
    shift = np.array([r["centroid_shift"] for r in rows])
    return {
        "shape": shape,
        "poses": poses,
        "analytic_pixels_mean": float(np.mean([r["analytic_pixels"] for r in rows])),
        "render_only_mean": float(np.mean([r["render_only"] for r in rows])),
        "analytic_only_mean": float(np.mean([r["analytic_only"] for r in rows])),
        "iou_mean": float(np.mean([r["iou"] for r in rows])),
        "iou_min": float(np.min([r["iou"] for r in rows])),
        "centroid_shift_mean_px": shift.mean(0).tolist(),
        "centroid_shift_sd_px": shift.std(0).tolist(),
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--poses", type=int, default=150)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_mask_gap.json"))
    args = ap.parse_args(argv)
    if args.poses < 1:
        ap.error(f"--poses must be >= 1, got {args.poses}")
    from mjx_push import scene

    rows = [measure(s, args.poses, args.seed) for s in scene.SHAPES]
    print("shape     pixels  render-only  analytic-only  IoU mean / min   centroid shift (px)")
    for r in rows:
        print(
            f"{r['shape']:<9} {r['analytic_pixels_mean']:6.1f}  {r['render_only_mean']:11.2f}  "
            f"{r['analytic_only_mean']:13.2f}  {r['iou_mean']:.4f} / {r['iou_min']:.3f}  "
            f"{np.round(r['centroid_shift_mean_px'], 3).tolist()}"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"spec": {"poses": args.poses, "seed": args.seed}, "shapes": rows}, indent=1) + "\n")
    print(f"written {args.out}")


if __name__ == "__main__":
    xla.use_cpu_devices()
    main()
