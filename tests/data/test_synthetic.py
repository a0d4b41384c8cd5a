"""Tests for the synthetic scene generator (``ftgspp synth``).

Geometry is checked independently of the generator: cameras are rebuilt from the written
files (``poses_bounds.npy`` by the DyNeRF convention, ``intri/extri.yml`` by EasyVolcap's),
and spheres are re-intersected analytically from ``trajectories.json``.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from ftgspp.data.synthetic.build import generate, main
from ftgspp.data.synthetic.pool import map_in_processes
from ftgspp.errors import InputError

SMALL = dict(n_cameras=4, n_frames=6, width=96, height=72)


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("synth")
    return {
        "dynerf": generate(root / "dynerf", layout="dynerf", seed=3, **SMALL),
        "easyvolcap": generate(root / "ev", layout="easyvolcap", seed=3, **SMALL),
        "fast": generate(root / "fast", layout="easyvolcap", preset="fast_motion", seed=3, **SMALL),
        "static": generate(root / "static", layout="easyvolcap", preset="static", seed=3, **SMALL),
    }


# ----------------------------------------------------------------------------- helpers


def load_json(path: Path) -> dict:
    return json.loads(path.read_text())


def camera_from_poses_bounds(row: np.ndarray):
    """(K, c2w [3, 3] OpenCV axes, centre, H, W) from one row, by the stated convention."""
    P = row[:15].reshape(3, 5)  # columns [down, right, back, centre, (H, W, focal)]
    H, W, f = P[:, 4]
    c2w = np.stack([P[:, 1], P[:, 0], -P[:, 2]], axis=1)  # OpenCV columns = [P1, P0, -P2]
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])
    return K, c2w, P[:, 3], int(H), int(W)


def project(K, c2w, centre, X) -> np.ndarray:
    x = c2w.T @ (np.asarray(X) - centre)
    return (K @ x)[:2] / x[2]


def sphere_on_pixels(K, c2w, centre, H, W, c, r):
    """Analytic first hit of every pixel-centre ray with a sphere: (hit [H, W], z-depth [H, W])."""
    jj, ii = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    d_cam = np.stack([(jj - K[0, 2]) / K[0, 0], (ii - K[1, 2]) / K[1, 1], np.ones_like(jj)], -1)
    d = d_cam @ c2w.T  # camera-z component 1: ray parameter = z-depth
    oc = centre - np.asarray(c)
    a, b = (d * d).sum(-1), d @ oc
    disc = b * b - a * (oc @ oc - r * r)
    t = (-b - np.sqrt(np.maximum(disc, 0))) / a
    return disc > 0, t, d


def read_pngs(scene: Path, cam: str) -> np.ndarray:
    files = sorted((scene / "images" / cam).glob("*.png"))
    return np.stack([cv2.imread(str(f))[..., ::-1] for f in files])


def read_video(path: Path) -> np.ndarray:
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame[..., ::-1])
    return np.stack(frames)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


# ----------------------------------------------------------------------------- tests


def test_same_seed_gives_identical_files(scenes, tmp_path):
    # the same bytes from one process as from cameras rendered side by side in two
    for (layout, ref), workers in zip((("dynerf", scenes["dynerf"]), ("easyvolcap", scenes["easyvolcap"])), (1, 2)):
        again = generate(tmp_path / layout, layout=layout, seed=3, workers=workers, **SMALL)
        files = sorted(p.relative_to(ref) for p in ref.rglob("*") if p.is_file())
        assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
        for rel in files:
            assert (ref / rel).read_bytes() == (again / rel).read_bytes(), rel
    other = generate(tmp_path / "seed4", layout="dynerf", seed=4, **SMALL)
    assert (other / "cam00.mp4").read_bytes() != (scenes["dynerf"] / "cam00.mp4").read_bytes()


def test_layout_files_and_gt_formats(scenes):
    dyn, ev = scenes["dynerf"], scenes["easyvolcap"]
    F, H, W, N = SMALL["n_frames"], SMALL["height"], SMALL["width"], SMALL["n_cameras"]
    names = [f"cam{k:02d}" for k in range(N)]
    assert sorted(p.stem for p in dyn.glob("cam*.mp4")) == names
    assert sorted(p.name for p in (ev / "images").iterdir()) == names
    assert len(list((ev / "images" / "cam00").glob("*.png"))) == F
    assert (ev / "images" / "cam00" / "000000.png").exists()
    info = load_json(dyn / "gt" / "scene.json")
    assert info["camera_names"] == names and info["n_frames"] == F and info["fps"] == 30.0
    assert info["preset"] == "studio" and info["seed"] == 3 and info["params"]["width"] == W
    for cam in names:
        depth = np.load(dyn / "gt" / "depth" / f"{cam}.npy")
        flow = np.load(dyn / "gt" / "flow3d" / f"{cam}.npy")
        objects = np.load(dyn / "gt" / "objects" / f"{cam}.npy")
        assert depth.shape == (F, H, W) and depth.dtype == np.float32 and np.all(depth > 0)
        assert flow.shape == (F, H, W, 3) and flow.dtype in (np.float16, np.float32)
        assert objects.shape == (F, H, W) and objects.dtype == np.uint8
        assert set(np.unique(objects)) <= {0, 1, 2}
    ct = load_json(dyn / "gt" / "color_transforms.json")["cameras"]
    assert sorted(ct) == names and np.array(ct["cam01"]["dM"]).shape == (3, 3)


def test_poses_bounds_format_and_near_far(scenes):
    dyn = scenes["dynerf"]
    pb = np.load(dyn / "poses_bounds.npy")
    assert pb.shape == (SMALL["n_cameras"], 17) and pb.dtype == np.float64
    for k, row in enumerate(pb):
        K, c2w, centre, H, W = camera_from_poses_bounds(row)
        assert (H, W) == (SMALL["height"], SMALL["width"])
        assert np.allclose(c2w.T @ c2w, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(c2w), 1.0)
        depth = np.load(dyn / "gt" / "depth" / f"cam{k:02d}.npy")
        near, far = row[15], row[16]
        assert depth.min() <= near < far <= depth.max()
        assert far / near > 5  # the far backdrop makes the depth range matter
    # cam00 sits in the middle of the arc: its centre is the closest to the rig's mean
    centres = pb[:, :15].reshape(-1, 3, 5)[:, :, 3]
    assert np.argmin(np.linalg.norm(centres - centres.mean(0), axis=1)) == 0


def test_poses_bounds_camera_sees_spheres_where_the_masks_are(scenes):
    """Projecting the trajectories with cameras rebuilt from poses_bounds matches gt masks and depth."""
    dyn = scenes["dynerf"]
    pb = np.load(dyn / "poses_bounds.npy")
    traj = load_json(dyn / "gt" / "trajectories.json")["objects"]
    for k, row in enumerate(pb):
        K, c2w, C, H, W = camera_from_poses_bounds(row)
        objects = np.load(dyn / "gt" / "objects" / f"cam{k:02d}.npy")
        depth = np.load(dyn / "gt" / "depth" / f"cam{k:02d}.npy")
        for f in range(SMALL["n_frames"]):
            for obj in traj:
                centre, r = np.array(obj["position"][f]), obj["radius"]
                hit, t, _ = sphere_on_pixels(K, c2w, C, H, W, centre, r)
                mask = objects[f] == obj["label"]
                assert mask.sum() > 20
                assert np.sum(mask & ~hit) == 0  # occlusion may remove pixels, never add them
                assert np.allclose(depth[f][mask], t[mask], rtol=1e-5)
                if k == 0:  # nothing occludes the balls in the middle view
                    assert np.sum(mask & hit) / np.sum(mask | hit) > 0.99
                    x, y = project(K, c2w, C, centre)
                    ii, jj = np.nonzero(mask)
                    assert abs(jj.mean() - x) < 0.6 and abs(ii.mean() - y) < 0.6
                    i, j = int(round(y)), int(round(x))
                    assert mask[i, j] and abs(depth[f, i, j] - t[i, j]) < 1e-4 * t[i, j]


def test_easyvolcap_cameras_match_poses_bounds(scenes):
    ev, pb = scenes["easyvolcap"], np.load(scenes["dynerf"] / "poses_bounds.npy")
    intri = cv2.FileStorage(str(ev / "intri.yml"), cv2.FILE_STORAGE_READ)
    extri = cv2.FileStorage(str(ev / "extri.yml"), cv2.FILE_STORAGE_READ)
    node = intri.getNode("names")
    names = [node.at(i).string() for i in range(node.size())]
    assert names == [f"cam{k:02d}" for k in range(SMALL["n_cameras"])]
    traj = load_json(ev / "gt" / "trajectories.json")["objects"]
    for k, name in enumerate(names):
        K = intri.getNode(f"K_{name}").mat()
        assert np.all(intri.getNode(f"D_{name}").mat() == 0)
        assert int(intri.getNode(f"H_{name}").real()) == SMALL["height"]
        assert int(intri.getNode(f"W_{name}").real()) == SMALL["width"]
        R = cv2.Rodrigues(extri.getNode(f"R_{name}").mat())[0]
        assert np.allclose(R, extri.getNode(f"Rot_{name}").mat(), atol=1e-9)
        T = extri.getNode(f"T_{name}").mat().reshape(3)
        K2, c2w, C, _, _ = camera_from_poses_bounds(pb[k])
        assert np.allclose(K, K2) and np.allclose(R, c2w.T, atol=1e-9) and np.allclose(-R.T @ T, C)
        # x_cam = R X + T puts ball_linear's centre inside its mask
        X = np.array(traj[0]["position"][0])
        x = K @ (R @ X + T)
        j, i = np.round(x[:2] / x[2]).astype(int)
        assert np.load(ev / "gt" / "objects" / f"{name}.npy")[0, i, j] == traj[0]["label"]


def test_scene_flow_equals_trajectory_velocity(scenes):
    dyn = scenes["dynerf"]
    pb = np.load(dyn / "poses_bounds.npy")
    traj = load_json(dyn / "gt" / "trajectories.json")
    lin, arc = traj["objects"]
    assert (lin["kind"], arc["kind"]) == ("linear", "curved")
    dt = 1.0 / traj["fps"]
    for obj in (lin, arc):  # velocities are the derivative of the positions (central differences)
        pos, vel = np.array(obj["position"]), np.array(obj["velocity"])
        fd = (pos[2:] - pos[:-2]) / (2 * dt)
        assert np.allclose(fd, vel[1:-1], rtol=1e-3, atol=1e-4)
    K, c2w, C, H, W = camera_from_poses_bounds(pb[0])
    flow = np.load(dyn / "gt" / "flow3d" / "cam00.npy").astype(np.float64)
    objects = np.load(dyn / "gt" / "objects" / "cam00.npy")
    depth = np.load(dyn / "gt" / "depth" / "cam00.npy").astype(np.float64)
    _, _, d = sphere_on_pixels(K, c2w, C, H, W, np.zeros(3), 1.0)
    for f in range(SMALL["n_frames"]):
        m1, m2 = objects[f] == lin["label"], objects[f] == arc["label"]
        assert np.allclose(flow[f][m1], lin["velocity"][f], atol=2e-3)  # ball_linear does not spin
        p = C + depth[f][m2][:, None] * d[m2]  # surface points from the depth map
        expected = np.array(arc["velocity"][f]) + np.cross(arc["angular_velocity"], p - arc["position"][f])
        assert np.allclose(flow[f][m2], expected, atol=5e-3)
        assert np.all(flow[f][objects[f] == 0] == 0)


def test_video_decodes_to_source_frames(scenes, tmp_path):
    dyn, ev = scenes["dynerf"], scenes["easyvolcap"]  # same seed and options: same frames
    for cam in ("cam00", "cam03"):
        video, pngs = read_video(dyn / f"{cam}.mp4"), read_pngs(ev, cam)
        assert video.shape == pngs.shape == (SMALL["n_frames"], SMALL["height"], SMALL["width"], 3)
        assert psnr(video, pngs) == float("inf")  # default codec (FFV1) is lossless
    lossy = generate(tmp_path / "mp4v", codec="mp4v", n_cameras=2, n_frames=4, width=128, height=96, seed=3)
    lossless = generate(tmp_path / "ffv1", layout="easyvolcap", n_cameras=2, n_frames=4, width=128, height=96, seed=3)
    video = read_video(lossy / "cam00.mp4")
    assert len(video) == 4
    assert psnr(video, read_pngs(lossless, "cam00")) > 28  # mp4v: lossy (~32 dB at 256x192)


def test_color_transforms_are_the_applied_affine_maps(tmp_path):
    kw = dict(layout="easyvolcap", n_cameras=3, n_frames=1, width=96, height=72, noise=0.0, seed=5)
    clean = generate(tmp_path / "clean", color_shift=0.0, **kw)
    shifted = generate(tmp_path / "shifted", color_shift=2.0, **kw)
    ct = load_json(shifted / "gt" / "color_transforms.json")["cameras"]
    for cam, t in ct.items():
        I = read_pngs(clean, cam)[0].reshape(-1, 3) / 255.0
        O = read_pngs(shifted, cam)[0].reshape(-1, 3) / 255.0
        ok = np.all((O > 0) & (O < 1), axis=1)
        A = np.hstack([I[ok], np.ones((ok.sum(), 1))])
        fit = np.linalg.lstsq(A, O[ok], rcond=None)[0]  # [4, 3]: rows (I3 + dM), then b
        assert np.allclose(fit[:3] - np.eye(3), t["dM"], atol=4e-3)
        assert np.allclose(fit[3], t["b"], atol=3e-3)
        assert np.abs(np.diag(np.array(t["dM"]))).max() <= 0.1 + 1e-9  # gain +-5 % at strength 1


def test_static_preset_has_no_motion(scenes):
    st = scenes["static"]
    for cam in ("cam00", "cam02"):
        assert not np.any(np.load(st / "gt" / "flow3d" / f"{cam}.npy"))
        objects = np.load(st / "gt" / "objects" / f"{cam}.npy")
        depth = np.load(st / "gt" / "depth" / f"{cam}.npy")
        assert np.all(objects == objects[0]) and np.all(depth == depth[0])
        frames = read_pngs(st, cam).astype(float)
        assert np.abs(frames - frames[0]).mean() < 5  # only sensor noise changes


def test_presets_differ_in_motion_speed(scenes):
    def speeds(scene: Path) -> np.ndarray:
        objs = load_json(scene / "gt" / "trajectories.json")["objects"]
        return np.array([np.linalg.norm(o["velocity"], axis=1).mean() for o in objs])

    def mask_travel(scene: Path) -> float:  # image-space centroid travel in the test view
        objects = np.load(scene / "gt" / "objects" / "cam00.npy")
        cents = [np.argwhere(objects[f] == 1).mean(0) for f in (0, len(objects) - 1)]
        return float(np.linalg.norm(cents[1] - cents[0]))

    studio, fast, static = speeds(scenes["easyvolcap"]), speeds(scenes["fast"]), speeds(scenes["static"])
    assert np.all(studio > 0.2) and np.all(fast > 3 * studio) and np.all(static == 0)
    assert mask_travel(scenes["fast"]) > 3 * mask_travel(scenes["easyvolcap"]) > 0


def test_speed_knob_scales_velocities(tmp_path):
    base = generate(tmp_path / "a", layout="easyvolcap", n_cameras=2, n_frames=2, width=32, height=24)
    fast = generate(tmp_path / "b", layout="easyvolcap", n_cameras=2, n_frames=2, width=32, height=24, speed=2.5)
    v0 = [np.array(o["velocity"]) for o in load_json(base / "gt" / "trajectories.json")["objects"]]
    v1 = [np.array(o["velocity"]) for o in load_json(fast / "gt" / "trajectories.json")["objects"]]
    for a, b in zip(v0, v1):
        assert np.allclose(np.linalg.norm(b, axis=1), 2.5 * np.linalg.norm(a, axis=1))


def test_errors_and_cli(tmp_path, capsys):
    with pytest.raises(InputError, match="unknown preset 'nope'"):
        generate(tmp_path / "x", preset="nope")
    assert main(["--out", str(tmp_path / "y"), "--preset", "nope"]) == 2
    assert "unknown preset 'nope' (choose from" in capsys.readouterr().err
    args = ["--out", str(tmp_path / "z"), "--cameras", "3", "--frames", "2", "--width", "32", "--height", "24",
            "--color-shift", "0.5", "--noise", "0", "--speed", "2", "--layout", "easyvolcap", "--seed", "7"]
    assert main(args) == 0
    params = load_json(tmp_path / "z" / "gt" / "scene.json")["params"]
    assert (params["n_cameras"], params["color_shift"], params["noise"], params["speed"]) == (3, 0.5, 0.0, 2.0)
    assert main(args) == 2  # refuses to write into a non-empty folder ...
    assert main(args + ["--overwrite"]) == 0  # ... unless asked to replace the earlier scene


def test_worker_processes_keep_the_order_and_report_a_failure():
    assert map_in_processes(math.sqrt, [(4.0,), (9.0,), (16.0,)], workers=2) == [2.0, 3.0, 4.0]
    with pytest.raises(RuntimeError, match="scene-rendering worker failed: ValueError: math domain error"):
        map_in_processes(math.sqrt, [(4.0,), (-1.0,)], workers=2)


def test_worker_processes_import_ftgspp_from_the_parents_tree():
    import ftgspp

    paths = map_in_processes(os.getenv, [("PYTHONPATH",), ("PYTHONPATH",)], workers=2)
    first = Path(paths[0].split(os.pathsep)[0])
    assert (first / "ftgspp" / "__init__.py").is_file()  # the repository, not its ftgspp/ folder
    assert first.resolve() == Path(ftgspp.__file__).resolve().parents[1]


def test_module_run_renders_cameras_in_worker_processes(tmp_path):
    # run as `python -m ftgspp.data.synthetic`, the module is __main__: workers must still find it
    out = tmp_path / "m"
    proc = subprocess.run([sys.executable, "-m", "ftgspp.data.synthetic", "--out", str(out), "--cameras", "2",
                           "--frames", "2", "--width", "32", "--height", "24"], capture_output=True, text=True,
                          env={**os.environ, "FTGSPP_SYNTH_WORKERS": "2"}, cwd=Path(__file__).resolve().parents[2])
    assert proc.returncode == 0, proc.stderr[-500:]
    again = generate(tmp_path / "serial", seed=0, workers=1, n_cameras=2, n_frames=2, width=32, height=24)
    assert (out / "cam01.mp4").read_bytes() == (again / "cam01.mp4").read_bytes()
