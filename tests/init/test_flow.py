"""Optical flow (DIS), forward-backward covisibility, the flow cache and flow-guided velocities.

Known motion comes from images built here: a textured image shifted by a sub-pixel
translation with ``cv2.warpAffine``, a textured square sliding over a textured background
(occlusion), and a textured plane translated rigidly in 3D, rendered exactly per camera
by ray-plane intersection (no dependency on the synthetic-scene generator).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from ftgspp.config import InitConfig
from ftgspp.data.scene import Camera, Scene
from ftgspp.errors import InputError
from ftgspp.init.flow import (
    DISFlow,
    FlowModel,
    flow_cache_dir,
    forward_backward_weight,
    get_flow_model,
    keyframe_flows,
    register_flow_model,
    sample_bilinear,
)  # fmt: skip
from ftgspp.init.flow_velocity import combine_views, flow_velocities, keyframe_flow_velocities

W, H, FOCAL = 128, 96, 110.0
FPS = 10.0
PLANE_Z = 3.0  # world plane z = PLANE_Z, seen by cameras near the origin looking along +z
VELOCITY = np.array([1.0, -0.6, 0.0])  # units / s, in the plane: 0.1 units (~3.7 px) per frame


def texture(size: int, seed: int, blur: float = 1.5) -> np.ndarray:
    """Random multi-scale texture, uint8 RGB [size, size, 3] (DIS needs gradients everywhere)."""
    rng = np.random.default_rng(seed)
    img = np.zeros((size, size, 3), np.float32)
    for cell, amp in ((32, 0.5), (8, 0.35), (2, 0.15)):
        small = rng.uniform(0, 1, (size // cell, size // cell, 3)).astype(np.float32)
        img += amp * cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC)
    img = cv2.GaussianBlur(img, (0, 0), blur)
    return np.clip(img * 255, 0, 255).astype(np.uint8)


def rgb_to_uint8(img: np.ndarray) -> np.ndarray:
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


# --------------------------------------------------------------------------- DIS + fb weight


def test_dis_recovers_subpixel_translation():
    img0 = texture(160, seed=0)
    shift = (2.35, -1.6)  # dst(x + dx, y + dy) = src(x, y): content moves by +shift
    M = np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]]])
    img1 = cv2.warpAffine(img0, M, (160, 160), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    flow = DISFlow("medium")(img0, img1)
    assert flow.shape == (160, 160, 2) and flow.dtype == np.float32
    inner = flow[12:-12, 12:-12].reshape(-1, 2)
    err = np.linalg.norm(inner - np.array(shift), axis=1)
    assert np.median(err) < 0.3


def test_fb_weight_matches_definition_on_analytic_flows():
    h, w = 20, 30
    fw = np.zeros((h, w, 2), np.float32)
    fw[..., 0] = 2.0  # everything moves 2 px right
    bw = -fw.copy()
    bw[:, 15:, 1] = 3.0  # inconsistent backward flow in the right half (where fw lands)
    weight = forward_backward_weight(fw, bw)
    assert weight.shape == (h, w) and weight.min() >= 0 and weight.max() <= 1
    # left part: round trip exact -> weight 1; pixels landing at x >= 15 see bw = (-2, 3):
    # r = (0, 3), sigma^2 = 0.01 (4 + 13) + 0.5
    np.testing.assert_allclose(weight[:, :12], 1.0, atol=1e-6)
    np.testing.assert_allclose(weight[:, 14:27], np.exp(-9.0 / (0.01 * 17 + 0.5)), rtol=1e-5)
    # pixels whose target leaves the image (x + 2 > w - 1) get 0
    assert np.all(weight[:, w - 2 :] == 0)


def test_fb_weight_low_where_background_gets_occluded():
    bg, fg = texture(128, seed=1), texture(128, seed=2, blur=1.0)
    img0, img1 = bg.copy(), bg.copy()
    y0, x0, s, move = 40, 30, 40, 10  # a textured square slides 10 px right over a static background
    img0[y0 : y0 + s, x0 : x0 + s] = fg[:s, :s]
    img1[y0 : y0 + s, x0 + move : x0 + move + s] = fg[:s, :s]
    dis = DISFlow()
    weight = forward_backward_weight(dis(img0, img1), dis(img1, img0))
    covered = weight[y0 + 6 : y0 + s - 6, x0 + s + 1 : x0 + s + move - 1]  # background hidden in img1
    static = weight[y0 + 6 : y0 + s - 6, 90:120]  # background far from the square
    on_square = weight[y0 + 8 : y0 + s - 8, x0 + 8 : x0 + s - 8]
    assert covered.mean() < 0.3
    assert static.mean() > 0.8 and on_square.mean() > 0.8


def test_sample_bilinear_against_direct_formula():
    rng = np.random.default_rng(0)
    img = rng.normal(size=(7, 9, 2)).astype(np.float32)
    xy = np.array([[0.0, 0.0], [8.0, 6.0], [3.25, 2.5], [7.9, 0.1], [-0.1, 3.0], [4.0, 6.2]])
    vals, inside = sample_bilinear(img, xy)
    assert inside.tolist() == [True, True, True, True, False, False]
    for (x, y), v, ok in zip(xy, vals, inside):
        if not ok:
            assert np.all(v == 0)
            continue
        x0, y0 = min(int(x), 7), min(int(y), 5)
        fx, fy = x - x0, y - y0
        expect = ((1 - fx) * (1 - fy) * img[y0, x0] + fx * (1 - fy) * img[y0, x0 + 1]
                  + (1 - fx) * fy * img[y0 + 1, x0] + fx * fy * img[y0 + 1, x0 + 1])  # fmt: skip
        np.testing.assert_allclose(v, expect, rtol=1e-5, atol=1e-6)


def test_registry():
    assert isinstance(get_flow_model("dis"), FlowModel)
    with pytest.raises(InputError, match="init.flow_model"):
        get_flow_model("nope")

    class Zero:
        name = "zero"

        def params(self) -> dict:
            return {}

        def __call__(self, img0, img1):
            return np.zeros(img0.shape[:2] + (2,), np.float32)

    register_flow_model("zero", Zero)
    assert get_flow_model("zero").name == "zero"


# --------------------------------------------------------------------------- a textured plane scene


def camera(name: str, center: np.ndarray, yaw_deg: float) -> Camera:
    """OpenCV camera at ``center`` looking along +z rotated by ``yaw_deg`` about the y axis."""
    a = np.deg2rad(yaw_deg)
    R_c2w = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    R = R_c2w.T
    K = np.array([[FOCAL, 0, (W - 1) / 2], [0, FOCAL, (H - 1) / 2], [0, 0, 1.0]])
    return Camera(name=name, K=K, R=R, T=-R @ center, width=W, height=H)


PLANE_TEX = texture(512, seed=7, blur=1.0)
TEX_HALF = 2.0  # texture covers x, y in [-2, 2] on the plane


def render_plane(cam: Camera, offset: np.ndarray) -> np.ndarray:
    """uint8 RGB image of the textured plane z = PLANE_Z translated by ``offset`` (in-plane)."""
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = np.stack([xx, yy, np.ones_like(xx)], -1) @ np.linalg.inv(cam.K).T @ cam.R  # world dirs
    c = cam.center
    t = (PLANE_Z - c[2]) / rays[..., 2]
    X = c + t[..., None] * rays  # [H, W, 3]
    u = (X[..., 0] - offset[0] + TEX_HALF) / (2 * TEX_HALF) * 511
    v = (X[..., 1] - offset[1] + TEX_HALF) / (2 * TEX_HALF) * 511
    return cv2.remap(PLANE_TEX, u.astype(np.float32), v.astype(np.float32), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REFLECT)  # fmt: skip


def plane_scene(tmp_path: Path, n_frames: int = 2, n_cams: int = 4) -> Scene:
    cams = [camera(f"cam{i:02d}", np.array([0.5 * (i - (n_cams - 1) / 2), 0.1 * (i % 2), 0.0]),
                   yaw_deg=6.0 * (i - (n_cams - 1) / 2)) for i in range(n_cams)]  # fmt: skip
    frames = {i: np.stack([render_plane(c, VELOCITY * f / FPS) for f in range(n_frames)]) for i, c in enumerate(cams)}
    return Scene(name="plane", root=tmp_path, cameras=cams, frame_ids=np.arange(n_frames), fps=FPS,
                 train_ids=list(range(n_cams)), test_ids=[], decode=lambda i: frames[i],
                 cache_dir=tmp_path / "cache")  # fmt: skip


def plane_points(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack([rng.uniform(-0.6, 0.6, n), rng.uniform(-0.4, 0.4, n), np.full(n, PLANE_Z)], axis=1)


class CountingDIS(DISFlow):
    calls = 0

    def __call__(self, img0, img1):
        type(self).calls += 1
        return super().__call__(img0, img1)


def test_flow_cache_hit_returns_stored_arrays(tmp_path):
    scene = plane_scene(tmp_path)
    model = CountingDIS()
    CountingDIS.calls = 0
    first = keyframe_flows(scene, 0, 1, model)
    assert CountingDIS.calls == 2 * len(scene.train_ids)  # forward + backward per camera
    assert first.timings["n_computed"] == 4 and first.timings["n_cached"] == 0
    files = sorted(flow_cache_dir(scene).glob("*.npy"))
    assert len(files) == 4 and all(f.parent == tmp_path / "cache" / "flow" for f in files)

    second = keyframe_flows(scene, 0, 1, model)
    assert CountingDIS.calls == 8  # nothing recomputed
    assert second.timings["n_cached"] == 4 and second.timings["compute_s"] == 0.0
    for c in scene.train_ids:
        assert np.array_equal(first.forward[c], second.forward[c])
        assert np.array_equal(first.backward[c], second.backward[c])

    # the file really is what is returned: overwrite one with a sentinel
    sentinel = np.full((2, H, W, 2), 7.0, np.float32)
    np.save(files[0], sentinel)
    third = keyframe_flows(scene, 0, 1, model)
    assert any(np.all(third.forward[c] == 7.0) for c in scene.train_ids)

    # other params, other frames or no cache -> recomputed
    keyframe_flows(scene, 0, 1, CountingDIS("fast"))
    assert CountingDIS.calls == 16
    keyframe_flows(scene, 1, 0, model)
    assert CountingDIS.calls == 24
    keyframe_flows(scene, 0, 1, model, use_cache=False)
    assert CountingDIS.calls == 32
    assert len(list(flow_cache_dir(scene).glob("*.npy"))) == 12


def test_flow_velocities_recover_plane_translation(tmp_path):
    scene = plane_scene(tmp_path)
    pts = plane_points(200)
    wrong_knn = np.tile(-VELOCITY + np.array([0.0, 0.0, 0.5]), (len(pts), 1))
    spacing = np.full(len(pts), 0.1)
    vel, accepted, stats = flow_velocities(scene, pts, 0, 1, wrong_knn, spacing, DISFlow(), tmp_path / "c")
    assert vel.shape == (200, 3) and vel.dtype == np.float32
    assert accepted.mean() > 0.95 and stats["n_accepted"] == accepted.sum()
    err = np.linalg.norm(vel - VELOCITY, axis=1)
    knn_err = np.linalg.norm(wrong_knn - VELOCITY, axis=1)
    speed = np.linalg.norm(VELOCITY)
    assert np.median(err[accepted]) < 0.1 * speed
    assert err.mean() < 0.2 * knn_err.mean()


def test_flow_velocities_fall_back_to_knn(tmp_path):
    scene = plane_scene(tmp_path)
    pts = plane_points(60, seed=1)
    pts[:20, 0] += 20.0  # far outside every view: no covisibility
    pts[20:30, 2] = -5.0  # behind every camera
    knn = np.random.default_rng(3).normal(size=(60, 3))
    spacing = np.full(60, 0.1)
    spacing[30:40] = 0.01  # flow displacement 0.117 > 3 * 0.01: implausibly far for the spacing
    vel, accepted, stats = flow_velocities(scene, pts, 0, 1, knn, spacing, DISFlow(), tmp_path / "c")
    assert not accepted[:40].any() and accepted[40:].mean() > 0.9
    np.testing.assert_array_equal(vel[:40], knn[:40].astype(np.float32))
    assert stats["n_low_weight"] >= 30 and stats["n_too_far"] >= 10


def test_keyframe_flow_velocities_last_keyframe_looks_back(tmp_path):
    scene = plane_scene(tmp_path, n_frames=3, n_cams=3)
    pts = [plane_points(50, seed=s) + VELOCITY * s / FPS for s in range(3)]
    knn = [np.zeros((50, 3)) for _ in range(3)]
    spacing = [np.full(50, 0.1) for _ in range(3)]
    vels, stats = keyframe_flow_velocities(scene, [0, 1, 2], pts, knn, spacing, InitConfig(), tmp_path / "c")
    for v in vels:  # the last keyframe (backward flow, negative dt) moves the same way
        assert np.median(np.linalg.norm(v - VELOCITY, axis=1)) < 0.1 * np.linalg.norm(VELOCITY)
    assert stats["n_points"] == 150
    # the backward interval reuses the cached pair of the forward one: 2 intervals x 3 cameras
    assert len(list((tmp_path / "c" / "flow").glob("*.npy"))) == 6
    single, _ = keyframe_flow_velocities(scene, [0], pts[:1], knn[:1], spacing[:1], InitConfig(), tmp_path / "c")
    np.testing.assert_array_equal(single[0], knn[0])


def test_combine_views_lsq_recovers_full_3d_motion():
    # three orthogonal views, each seeing the motion without its own axis component
    d = np.array([0.3, -0.2, 0.5])
    axes = np.eye(3)
    disp = np.stack([d - (d @ a) * a for a in axes])[:, None, :]  # [3, 1, 3]
    w = np.ones((3, 1))
    np.testing.assert_allclose(combine_views(disp, w, axes, "lsq", damping=0.0), d[None], atol=1e-9)
    # shared axis: lsq = weighted mean in the plane, zero along the axis
    same = np.tile(np.array([[0.0, 0.0, 1.0]]), (2, 1))
    disp2 = np.array([[[0.2, 0.1, 0.0]], [[0.4, -0.1, 0.0]]])
    w2 = np.array([[1.0], [3.0]])
    mean = combine_views(disp2, w2, same, "mean")
    np.testing.assert_allclose(mean, [[0.35, -0.05, 0.0]])
    np.testing.assert_allclose(combine_views(disp2, w2, same, "lsq", damping=0.01), mean, rtol=1e-3)


def test_combine_rays_recovers_motion_along_every_views_axis():
    """The moved point nearest every view's moved ray is the true moved point, depth included,
    where averaging constant-depth displacements loses the motion along the views' axes."""
    from ftgspp.init.flow_velocity import combine_rays

    X = np.array([[0.2, -0.1, 5.0], [1.0, 0.5, 6.0]])  # [M, 3]
    d = np.array([[0.05, 0.0, 0.6], [-0.1, 0.2, -0.3]])  # mostly along depth
    centers = np.array([[-2.0, 0.0, 0.0], [0.0, 0.0, 0.0], [2.0, 0.5, 0.0], [0.5, -1.5, 0.0]])  # [C, 3]
    rays = X[None] + d[None] - centers[:, None]  # [C, M, 3] through the moved points
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    w = np.ones((len(centers), len(X)))
    np.testing.assert_allclose(combine_rays(X, centers, rays, w, damping=0.0), d, atol=1e-9)
    damped = combine_rays(X, centers, rays, w)  # the default damping barely shrinks a seen motion
    assert np.all(np.linalg.norm(damped - d, axis=1) < 0.05 * np.linalg.norm(d, axis=1))
    # the constant-depth displacement each view would report, averaged: the depth part is lost
    axes = np.tile([0.0, 0.0, 1.0], (len(centers), 1))
    disp = np.stack([np.where(np.arange(3) < 2, d * 5.0 / (5.0 + d[:, 2:]), 0.0) for _ in centers])
    assert np.all(np.abs(combine_views(disp, w, axes, "mean")[:, 2]) < 1e-12)


def test_rays_keep_the_depth_motion_that_the_mean_loses(tmp_path):
    """A generated scene whose balls move mostly along depth (toward the cameras): the flow-guided
    initial velocity's median error on moving points, as a share of their true speed."""
    from dataclasses import replace

    from ftgspp.config import DataConfig
    from ftgspp.data.load import load_scene
    from ftgspp.data.synthetic.build import generate
    from ftgspp.init import initialize

    root = generate(tmp_path / "depth", preset="studio", seed=0, width=128, height=96, n_frames=11,
                    linear_velocity=(0.1, 0.0, 0.9), orbit_omega=0.0, spin=0.0)
    scene = load_scene(DataConfig(path=str(root)))
    share = {}
    for combine in ("mean", "rays"):
        cfg = replace(InitConfig(), velocity="flow", flow_combine=combine, keyframe_stride=5)
        st = initialize(scene, cfg, 3000, seed=0).stats
        share[combine] = st["init_velocity_error_moving"] / st["init_velocity_true_speed_moving"]
    print(f"depth-motion scene: median error / true speed, mean {share['mean']:.2f}, rays {share['rays']:.2f}")
    assert share["rays"] < 0.35 and share["mean"] > 0.6, share
