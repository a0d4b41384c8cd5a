"""Flow-guided vs kNN initial velocities against ground truth on a synthetic scene.

Triangulates the keyframe points like ``ftgspp.init.initialize`` (before the budget is
fitted), computes kNN velocities and flow-guided velocities (DIS, cached flows), and scores
both against the true velocity of every point: for points on a moving sphere (within
``--surface-tol`` of its surface at the keyframe time) v_gt = v_centre + ω × (X − c) from
``gt/trajectories.json``; every other point is static (v_gt = 0). Flow time is measured
twice: cold (cache cleared) and warm (from the cache).

    python benchmarks/flow_vs_knn.py                      # generates the studio scene in /tmp
    python benchmarks/flow_vs_knn.py --scene /tmp/fg/studio --downsample 2 --combine mean
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np

from ftgspp.config import DataConfig, InitConfig
from ftgspp.data.load import load_scene
from ftgspp.init.flow import FlowSet, flow_cache_dir, get_flow_model, keyframe_flows
from ftgspp.init.flow_velocity import flow_velocities
from ftgspp.init.points import depth_range, keyframes, triangulate_keyframe
from ftgspp.init.spacing import knn_spacing
from ftgspp.init.velocity import knn_velocity


def true_velocities(points: np.ndarray, t: float, traj: dict, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """``(v_gt [M, 3], label [M])``: rigid-body velocity on a moving sphere, else 0 (label 0)."""
    v = np.zeros_like(points)
    label = np.zeros(len(points), dtype=np.int64)
    times = np.asarray(traj["times"])
    for o in traj["objects"]:
        f = int(np.abs(times - t).argmin())
        assert abs(times[f] - t) < 1e-6, "keyframe time not in the trajectory table"
        c, vc, w = (np.asarray(o[k][f] if k != "angular_velocity" else o[k]) for k in ("position", "velocity",
                                                                                      "angular_velocity"))
        r = points - c
        on = np.abs(np.linalg.norm(r, axis=1) - o["radius"]) < tol
        v[on] = vc + np.cross(w, r[on])
        label[on] = o["label"]
    return v, label


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="/tmp/ftgspp_bench/studio", help="synthetic scene (generated if absent)")
    ap.add_argument("--preset", default="studio")
    ap.add_argument("--downsample", type=float, default=2.0)
    ap.add_argument("--stride", type=int, default=10)
    ap.add_argument("--combine", default="mean", choices=["mean", "lsq"])
    ap.add_argument("--occlusion", action="store_true", help="point-cloud visibility test")
    ap.add_argument("--surface-tol", type=float, default=0.05, help="distance to a sphere's surface (units)")
    ap.add_argument("--json", default=None, help="write the numbers here")
    args = ap.parse_args(argv)

    root = Path(args.scene)
    if not (root / "gt" / "trajectories.json").is_file():
        from ftgspp.data.synthetic.build import generate

        print(f"generating {args.preset} into {root} ...")
        generate(root, layout="dynerf", preset=args.preset, seed=0, overwrite=True)
    scene = load_scene(DataConfig(path=str(root), downsample=args.downsample))
    traj = json.loads((root / "gt" / "trajectories.json").read_text())
    cfg = InitConfig(keyframe_stride=args.stride, velocity="knn")
    near, far = depth_range(scene, cfg)
    kfs = keyframes(scene, cfg)
    model = get_flow_model("dis")
    shutil.rmtree(flow_cache_dir(scene), ignore_errors=True)

    rows = []
    cold = warm = 0.0
    for i, f in enumerate(kfs):
        j = i + 1 if i + 1 < len(kfs) else i - 1
        pts, _ = triangulate_keyframe(scene, f, cfg, near, far)
        nxt, _ = triangulate_keyframe(scene, kfs[j], cfg, near, far)
        dt = float(scene.times[kfs[j]] - scene.times[f])
        v_knn = knn_velocity(pts, nxt, dt, k=cfg.knn_k)
        spacing = knn_spacing(pts.astype(np.float64))
        a, b = sorted((f, kfs[j]))
        flows = keyframe_flows(scene, a, b, model)  # cold (cache cleared above), or the shared interval
        cold += flows.timings["compute_s"]
        flows = keyframe_flows(scene, a, b, model)  # warm: from the cache
        warm += flows.timings["load_s"]
        if j < i:
            flows = FlowSet(f, kfs[j], flows.backward, flows.forward, flows.timings)
        v_flow, acc, st = flow_velocities(scene, pts, f, kfs[j], v_knn, spacing, model, flows=flows,
                                          combine=args.combine, occlusion=args.occlusion)  # fmt: skip
        v_gt, label = true_velocities(pts.astype(np.float64), float(scene.times[f]), traj, args.surface_tol)
        rows.append((v_knn, v_flow, v_gt, label, acc))
        print(f"keyframe {f:3d} -> {kfs[j]:3d}: {len(pts)} points, {int((label > 0).sum())} on moving objects, "
              f"{st['accepted_fraction']:.1%} flow-accepted")

    v_knn, v_flow, v_gt, label, acc = (np.concatenate(x) for x in zip(*rows))
    err = {name: np.linalg.norm(v - v_gt, axis=1) for name, v in (("knn", v_knn), ("flow", v_flow))}
    dyn, sta = label > 0, label == 0
    gt_speed = float(np.linalg.norm(v_gt[dyn], axis=1).mean())
    out = {
        "scene": str(root), "downsample": args.downsample, "stride": args.stride, "combine": args.combine,
        "occlusion": args.occlusion, "n_points": int(len(label)), "n_dynamic": int(dyn.sum()),
        "accepted_fraction": float(acc.mean()), "accepted_fraction_dynamic": float(acc[dyn].mean()),
        "mean_gt_speed_dynamic": gt_speed,
        "flow_seconds_cold": cold, "flow_seconds_cached": warm,
    }  # fmt: skip
    for name, e in err.items():
        out[f"{name}_epe_dynamic_mean"] = float(e[dyn].mean())
        out[f"{name}_epe_dynamic_median"] = float(np.median(e[dyn]))
        out[f"{name}_speed_static_mean"] = float(e[sta].mean())
        for o in traj["objects"]:
            sel = label == o["label"]
            if sel.any():
                out[f"{name}_epe_{o['name']}"] = float(e[sel].mean())
    print(json.dumps(out, indent=2))
    print(f"moving points: kNN EPE {out['knn_epe_dynamic_mean']:.4f}, flow EPE {out['flow_epe_dynamic_mean']:.4f}"
          f" units/s (mean GT speed {gt_speed:.4f}); static points: kNN {out['knn_speed_static_mean']:.4f}, "
          f"flow {out['flow_speed_static_mean']:.4f}; flow time {cold:.2f} s cold, {warm:.3f} s cached")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
