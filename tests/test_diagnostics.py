"""Diagnostics: lifetimes (against a numeric search), flow colour coding, pixel velocities
(against finite differences), x–t slices, motion error of hand-built moving models, and the
end-to-end ``run_diagnostics`` / ``ftgspp diagnose`` outputs.

The scenes are built here: one camera looking along +z at a wall of small opaque Gaussians
(depth 4) with an optional moving square of Gaussians in front of it (depth 3).
"""

from __future__ import annotations

import colorsys
import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.optimize import brentq

from ftgspp.config import InitConfig, ModelConfig, TrainConfig
from ftgspp.data.scene import Camera, Scene
from ftgspp.diagnostics.diagnose import run_diagnostics
from ftgspp.diagnostics.flow_colors import color_wheel, flow_to_rgb
from ftgspp.diagnostics.lifetimes import lifetime_fractions, lifetime_histogram, subset_model
from ftgspp.diagnostics.motion import composite, motion_error, pixel_velocities, velocity_map, xt_slice
from ftgspp.errors import InputError
from ftgspp.methods.freetime import FreeTimeGaussians, duration_to_param

W, H, FOCAL = 64, 48, 60.0
FPS = 10.0
WALL_Z, OBJ_Z = 4.0, 3.0
OBJ_HALF = 0.6  # the object square spans |x|, |y| < 0.6 (world units at depth 3)
V_OBJ = np.array([0.5, -0.25, 0.0])  # units / s


def camera(name: str = "cam00") -> Camera:
    K = np.array([[FOCAL, 0, (W - 1) / 2], [0, FOCAL, (H - 1) / 2], [0, 0, 1.0]])
    return Camera(name=name, K=K, R=np.eye(3), T=np.zeros(3), width=W, height=H)


# --------------------------------------------------------------------------- lifetimes


def lifetime_by_search(o: float, g: float, s: float, mu: float, theta: float) -> float:
    """Length of {t : o (g + (1 - g) a(t)) >= theta} by root finding (inf if always)."""
    f = lambda t: o * (g + (1 - g) * np.exp(-0.5 * ((t - mu) / s) ** 2)) - theta  # noqa: E731
    if f(mu) < 0:
        return 0.0
    if f(mu + 1e6 * s) >= 0:
        return np.inf
    return 2 * (brentq(f, mu, mu + 100 * s, xtol=1e-12) - mu)


@pytest.mark.parametrize("gate", [False, True])
def test_lifetimes_match_numeric_search_and_histogram(gate):
    rng = np.random.default_rng(0)
    n = 300
    cfg = ModelConfig(gate=gate, max_duration=1.0 if gate else None, sh_degree=0)
    model = FreeTimeGaussians.from_points(rng.normal(size=(n, 3)), rng.uniform(size=(n, 3)), rng.uniform(0, 1, n),
                                          np.zeros((n, 3)), np.full(n, 0.1), cfg, InitConfig())  # fmt: skip
    with torch.no_grad():
        model.params["opacities"].copy_(torch.from_numpy(rng.normal(0, 2, n)).float())
        model.params["durations"].copy_(torch.from_numpy(rng.normal(0, 1.5, n)).float())
        model.params["gates"].copy_(torch.from_numpy(rng.uniform(-0.3, 0.1, n)).float())
    duration, theta = 0.8, 0.05
    frac = lifetime_fractions(model, theta, duration)
    o = model.base_opacity().detach().double().numpy()
    g = model.gate().detach().double().numpy()
    s = model.temporal_scale().detach().double().numpy()
    mu = model.params["times"].detach().double().numpy()
    oracle = np.array([lifetime_by_search(o[i], g[i], s[i], mu[i], theta) for i in range(n)]) / duration
    finite = np.isfinite(oracle)
    assert np.array_equal(np.isfinite(frac), finite)
    if gate:
        assert (~finite).sum() > 10 and (oracle == 0).sum() > 10  # both extremes exercised
    np.testing.assert_allclose(frac[finite], oracle[finite], rtol=1e-4, atol=1e-6)
    counts, edges = lifetime_histogram(frac, bins=25, max_fraction=1.5)
    expect, expect_edges = np.histogram(np.minimum(oracle, 1.5), bins=25, range=(0, 1.5))
    assert np.array_equal(counts, expect) and np.allclose(edges, expect_edges)
    assert counts.sum() == n


# --------------------------------------------------------------------------- colour coding


@pytest.mark.parametrize(
    "direction, hue",
    [((1, 0), 0.0), ((1, 1), 1 / 8), ((0, 1), 0.25), ((-1, 0), 0.5), ((0, -1), 0.75), ((1, -1), 7 / 8)],
)
def test_flow_colour_hue_is_direction(direction, hue):
    flow = np.zeros((1, 2, 2))
    flow[0, 0] = np.array(direction, float) / np.linalg.norm(direction) * 3.0  # full speed
    flow[0, 1] = flow[0, 0] / 3.0  # a third of it
    rgb, vmax = flow_to_rgb(flow, max_magnitude=3.0)
    assert vmax == 3.0
    h, s, v = colorsys.rgb_to_hsv(*rgb[0, 0])
    assert min(abs(h - hue), 1 - abs(h - hue)) < 1e-6 and s == pytest.approx(1.0) and v == pytest.approx(1.0)
    h2, _, v2 = colorsys.rgb_to_hsv(*rgb[0, 1])
    assert v2 == pytest.approx(1 / 3) and min(abs(h2 - hue), 1 - abs(h2 - hue)) < 1e-6


def test_flow_colour_mask_and_wheel():
    flow = np.zeros((2, 2, 2))
    mask = np.array([[True, False], [True, True]])
    rgb, _ = flow_to_rgb(flow, 1.0, mask=mask)
    assert np.all(rgb[0, 1] == 1.0) and np.all(rgb[mask] == 0.0)  # no motion: black; masked: white
    wheel = color_wheel(41)
    assert wheel.shape == (41, 41, 3)
    np.testing.assert_allclose(wheel[20, 40], [1, 0, 0], atol=1e-6)  # right: red
    np.testing.assert_allclose(wheel[20, 0], [0, 1, 1], atol=1e-6)  # left: cyan
    assert colorsys.rgb_to_hsv(*wheel[40, 20])[0] == pytest.approx(0.25)  # down (+y)
    assert np.all(wheel[0, 0] == 1.0)  # outside the disc


# --------------------------------------------------------------------------- models and velocities


def wall_and_object(moving: bool = True, obj_velocity: np.ndarray = V_OBJ) -> tuple[FreeTimeGaussians, np.ndarray]:
    """Opaque static wall (z = 4) + square object (z = 3) moving with ``obj_velocity``.

    Returns the model and the object indicator ``[N]``. Gaussians are 0.06 apart with
    scale 0.05 (about a pixel), opacity 0.99, constant in time (huge temporal scale).
    """
    def grid(half_x, half_y, z, step):
        xs, ys = np.arange(-half_x, half_x + 1e-9, step), np.arange(-half_y, half_y + 1e-9, step)
        X, Y = np.meshgrid(xs, ys)
        return np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], axis=1)

    wall = grid(2.6, 2.0, WALL_Z, 0.06)
    obj = grid(OBJ_HALF, OBJ_HALF, OBJ_Z, 0.045)
    means = np.concatenate([wall, obj])
    is_obj = np.r_[np.zeros(len(wall), bool), np.ones(len(obj), bool)]
    vel = np.where(is_obj[:, None] & moving, obj_velocity, 0.0)
    colors = np.where(is_obj[:, None], [0.9, 0.2, 0.1], [0.2, 0.4, 0.8])
    cfg, init = ModelConfig(sh_degree=0), InitConfig(opacity=0.99, duration=1e3, scale_factor=1.0)
    n = len(means)
    model = FreeTimeGaussians.from_points(means, colors, np.zeros(n), vel, np.full(n, 0.05), cfg, init)
    return model, is_obj


def test_pixel_velocities_match_finite_differences():
    rng = np.random.default_rng(1)
    n = 50
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    R *= np.sign(np.linalg.det(R))  # a rotation
    cam = Camera("c", np.array([[70.0, 0, 30], [0, 65.0, 20], [0, 0, 1]]), R, rng.normal(size=3), 64, 48)
    forward = cam.R.T @ np.array([0, 0, 1.0])  # optical axis in world coordinates
    means = cam.center + forward * rng.uniform(2, 6, (n, 1)) + rng.normal(0, 0.5, (n, 3))
    model = FreeTimeGaussians.from_points(means, np.zeros((n, 3)), rng.uniform(0, 1, n), rng.normal(size=(n, 3)),
                                          np.full(n, 0.1), ModelConfig(sh_degree=0), InitConfig())  # fmt: skip
    t, eps = 0.4, 1e-4

    p = {k: v.detach().double().numpy() for k, v in model.params.items()}

    def proj(tt):  # float64 pinhole projection of the moving centres
        mu = p["means"] + p["velocities"] * (tt - p["times"])[:, None]
        xc = mu @ cam.R.T + cam.T
        uv = xc @ cam.K.T
        return uv[:, :2] / uv[:, 2:]

    fd = (proj(t + eps) - proj(t - eps)) / (2 * eps)
    np.testing.assert_allclose(pixel_velocities(model, cam, t).numpy(), fd, rtol=1e-4, atol=1e-4)


def test_velocity_map_of_a_translating_square():
    model, is_obj = wall_and_object()
    cam = camera()
    flow, alpha = velocity_map(model, cam, 0.0, FPS)
    assert flow.shape == (H, W, 2) and alpha.shape == (H, W)
    expect = FOCAL * V_OBJ[:2] / OBJ_Z / FPS  # px/frame of a fronto-parallel translation
    centre = flow[H // 2 - 8 : H // 2 + 8, W // 2 - 8 : W // 2 + 8].reshape(-1, 2)
    np.testing.assert_allclose(centre, np.broadcast_to(expect, centre.shape), rtol=1e-3, atol=1e-4)
    assert np.abs(flow[:, :4]).max() < 1e-6  # the static wall at the left edge
    rgb, _ = flow_to_rgb(flow, mask=alpha > 0.5)
    h = colorsys.rgb_to_hsv(*rgb[H // 2, W // 2])[0]  # right and up: hue between 3/4 and 1
    assert h == pytest.approx((np.arctan2(expect[1], expect[0]) / (2 * np.pi)) % 1.0, abs=1e-3)


def test_xt_slice_shape_and_content():
    frames = np.random.default_rng(0).integers(0, 255, size=(7, 12, 20, 3), dtype=np.uint8)
    sl = xt_slice(frames, 5)
    assert sl.shape == (7, 20, 3)
    assert np.array_equal(sl[3], frames[3, 5])


def object_masks(cam: Camera, t: float, margin_px: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
    """Object mask (uint8 [H, W]) of the square at time t and a band of +-margin around its edge."""
    c = V_OBJ * t
    x0, x1 = [FOCAL * (c[0] + s * OBJ_HALF) / OBJ_Z + cam.K[0, 2] for s in (-1, 1)]
    y0, y1 = [FOCAL * (c[1] + s * OBJ_HALF) / OBJ_Z + cam.K[1, 2] for s in (-1, 1)]
    yy, xx = np.mgrid[0:H, 0:W]
    inside = (xx >= x0) & (xx <= x1) & (yy >= y0) & (yy <= y1)
    dist = np.minimum.reduce([np.abs(xx - x0), np.abs(xx - x1), np.abs(yy - y0), np.abs(yy - y1)])
    edge = dist < margin_px
    return inside.astype(np.uint8), edge


def test_motion_error_zero_for_matching_flow_and_large_for_wrong():
    model, _ = wall_and_object()
    cam = camera()
    t = 0.2
    vel, alpha = composite(model, cam, t, model.params["velocities"].detach())
    objects, edge = object_masks(cam, t)
    alpha = np.where(edge, 0.0, alpha)  # mixed pixels at the silhouette are left out
    gt = np.where(objects[..., None] > 0, V_OBJ, 0.0)
    good = motion_error(vel, alpha, gt, objects)
    assert good["n_dynamic_px"] > 150 and good["n_static_px"] > 1000
    assert good["epe_dynamic"] < 1e-3 * np.linalg.norm(V_OBJ) and good["leak_static"] < 1e-4
    assert good["gt_speed_dynamic"] == pytest.approx(np.linalg.norm(V_OBJ), rel=1e-6)
    wrong = motion_error(vel, alpha, -gt, objects)  # object moving the other way
    assert wrong["epe_dynamic"] == pytest.approx(2 * np.linalg.norm(V_OBJ), rel=1e-3)
    # a model that moves the wall too leaks speed into the static region
    leaky, _ = wall_and_object()
    with torch.no_grad():
        leaky.params["velocities"][:] = torch.tensor(V_OBJ, dtype=torch.float32)
    v2, a2 = composite(leaky, cam, t, leaky.params["velocities"].detach())
    assert motion_error(v2, np.where(edge, 0.0, a2), gt, objects)["leak_static"] == pytest.approx(
        np.linalg.norm(V_OBJ), rel=1e-3)


def test_subset_model_keeps_only_the_selected_gaussians():
    model, is_obj = wall_and_object()
    sub = subset_model(model, is_obj)
    assert len(sub) == int(is_obj.sum())
    torch.testing.assert_close(sub.params["means"], model.params["means"][torch.from_numpy(is_obj)])


# --------------------------------------------------------------------------- end to end


def tiny_scene(tmp_path: Path, model: FreeTimeGaussians, is_obj: np.ndarray, n_frames: int = 4) -> Scene:
    """A one-camera scene whose frames are renders of ``model`` and whose gt/ matches it
    (object mask where the rendered object indicator is > 0.5: a short-lived object vanishes)."""
    cam = camera()
    times = np.arange(n_frames) / FPS
    ind = torch.from_numpy(is_obj[:, None]).float()  # [N, 1]
    colors = ind * torch.tensor([[0.9, 0.2, 0.1]]) + (1 - ind) * torch.tensor([[0.2, 0.4, 0.8]])
    frames, objs = [], []
    for t in times:
        rgb_ind, _ = composite(model, cam, t, torch.cat([colors, ind], dim=1))  # [H, W, 4]
        frames.append(np.clip(np.round(rgb_ind[..., :3] * 255), 0, 255).astype(np.uint8))
        objs.append((rgb_ind[..., 3] > 0.5).astype(np.uint8))
    frames, objs = np.stack(frames), np.stack(objs)
    gt = tmp_path / "gt"
    for sub in ("depth", "flow3d", "objects"):
        (gt / sub).mkdir(parents=True)
    np.save(gt / "objects" / "cam00.npy", objs)
    np.save(gt / "depth" / "cam00.npy", np.where(objs > 0, OBJ_Z, WALL_Z).astype(np.float32))
    np.save(gt / "flow3d" / "cam00.npy", np.where(objs[..., None] > 0, V_OBJ, 0.0).astype(np.float16))
    return Scene(name="tiny", root=tmp_path, cameras=[cam], frame_ids=np.arange(n_frames), fps=FPS, train_ids=[0],
                 test_ids=[0], decode=lambda i: frames, ground_truth=gt)  # fmt: skip


def test_run_diagnostics_writes_readable_outputs(tmp_path):
    model, is_obj = wall_and_object()
    with torch.no_grad():  # object short-lived (s = 0.04 s, gone after frame 1), wall long-lived
        model.params["durations"][torch.from_numpy(is_obj)] = duration_to_param(0.04, None)
    scene = tiny_scene(tmp_path, model, is_obj)
    cfg = TrainConfig()
    cfg.model.sh_degree = 0
    res = run_diagnostics(model, scene, cfg, tmp_path / "diag", frame=1)
    names = {"lifetime_histogram", "lifetime_groups", "velocity_map", "xt_slice", "motion_error", "json"}
    assert set(res.files) == names | {"xt_slice_arrays"}
    for name, path in res.files.items():
        assert Path(path).is_file() and Path(path).stat().st_size > (100 if name == "xt_slice_arrays" else 1000)
    with np.load(res.files["xt_slice_arrays"]) as xt:  # the figure's arrays: recorded frames' middle row, render's
        np.testing.assert_array_equal(xt["gt"], scene.frames(0)[:, H // 2])
        assert xt["render"].shape == (4, scene.cameras[0].width, 3) and int(xt["row"]) == H // 2 and "gt_clean" not in xt
    saved = json.loads((tmp_path / "diag" / "diagnostics.json").read_text())
    assert saved["lifetime"]["n_short_lived"] == int(is_obj.sum())
    assert saved["lifetime"]["n_long_lived"] == int((~is_obj).sum())
    # every classified long-lived Gaussian is on the static wall, every short-lived on the object
    assert saved["lifetime"]["long_lived_on_static"] == 1.0 and saved["lifetime"]["short_lived_on_dynamic"] == 1.0
    # motion: only silhouette pixels (mixed object / wall velocity) contribute to the error
    assert saved["motion"]["leak_static"] < 0.1 * np.linalg.norm(V_OBJ)
    assert saved["motion"]["epe_dynamic"] < 0.1 * np.linalg.norm(V_OBJ)
    # without figures: the same numbers, only diagnostics.json written
    bare = run_diagnostics(model, scene, cfg, tmp_path / "bare", frame=1, figures=False)
    assert set(bare.files) == {"json", "xt_slice_arrays"}  # the arrays are kept without figures too
    assert sorted(p.name for p in (tmp_path / "bare").iterdir()) == ["diagnostics.json", "xt_slice.npz"]
    np.testing.assert_equal(bare.metrics(), res.metrics())  # NaN where a score has no pixels
    bare_saved = json.loads((tmp_path / "bare" / "diagnostics.json").read_text())
    assert bare_saved.pop("files") == {"xt_slice_arrays": str(tmp_path / "bare" / "xt_slice.npz")}
    assert bare_saved == {k: v for k, v in saved.items() if k != "files"}


def test_diagnose_cli_on_a_generated_scene(tmp_path, capsys):
    from ftgspp.data.synthetic.build import generate
    from ftgspp.diagnostics.diagnose import main

    root = generate(tmp_path / "scene", layout="easyvolcap", preset="studio", seed=0,
                    n_cameras=3, n_frames=3, width=48, height=36, supersample=1)  # fmt: skip
    model, _ = wall_and_object(moving=True)
    run = tmp_path / "run"
    run.mkdir()
    cfg = TrainConfig()
    cfg.data.path = str(root)
    cfg.model = ModelConfig(sh_degree=0)
    (run / "config.json").write_text(json.dumps(asdict(cfg)))
    torch.save({k: v.detach() for k, v in model.params.items()}, run / "gaussians.pt")
    assert main([str(run), "--theta", "0.1", "--frame", "1"]) == 0
    printed = capsys.readouterr().out.split()
    assert len(printed) == 7 and all(Path(p).is_file() for p in printed)
    assert Path(printed[0]).parent == run / "diagnostics"
    saved = json.loads((run / "diagnostics" / "diagnostics.json").read_text())
    assert saved["theta"] == 0.1 and saved["frame"] == 1 and "motion" in saved
    # the same run read from another folder: its relative scene path means nothing there
    cfg.data.path = "data/synth/studio-elsewhere"
    (run / "config.json").write_text(json.dumps(asdict(cfg)))
    with pytest.raises(InputError, match="give the scene with --data DIR"):
        main([str(run)])
    assert main([str(run), "--data", str(root), "--theta", "0.1"]) == 0


def test_transient_share_is_measured_where_the_scene_marks_transient_pixels(tmp_path):
    """The object exists only at the start (short-lived Gaussians): on its pixels nearly all the
    weight is short-lived, on static pixels none, so the transient contrast is close to 1; a
    scene without ``gt/transient`` reports no transient numbers."""
    model, is_obj = wall_and_object()
    with torch.no_grad():
        model.params["durations"][torch.from_numpy(is_obj)] = duration_to_param(0.04, None)
    scene = tiny_scene(tmp_path, model, is_obj)
    cfg = TrainConfig()
    cfg.model.sh_degree = 0
    plain = run_diagnostics(model, scene, cfg, tmp_path / "plain", frame=1).metrics()
    assert "lifetime_transient_contrast" not in plain
    (tmp_path / "gt" / "transient").mkdir()
    np.save(tmp_path / "gt" / "transient" / "cam00.npy", np.load(tmp_path / "gt" / "objects" / "cam00.npy"))
    m = run_diagnostics(model, scene, cfg, tmp_path / "diag", frame=1).metrics()
    assert m["lifetime_short_share_transient"] > 0.9 and m["lifetime_short_share_static"] < 0.1
    assert m["lifetime_transient_contrast"] == pytest.approx(
        m["lifetime_short_share_transient"] - m["lifetime_short_share_static"])


@pytest.mark.parametrize("src,dst", [(192, 96), (256, 128), (1014, 507), (1352, 451), (37, 100), (50, 50), (7, 3)])
def test_nearest_indices_pick_the_pixels_of_cv2s_nearest_resize(src, dst):
    import cv2

    from ftgspp.diagnostics.motion import nearest_indices

    a = np.random.default_rng(src).random((src, 9), dtype=np.float32)
    ref = cv2.resize(a, (9, dst), interpolation=cv2.INTER_NEAREST)  # the rows
    np.testing.assert_array_equal(a[nearest_indices(src, dst)], ref)
    ref = cv2.resize(a.T.copy(), (dst, 9), interpolation=cv2.INTER_NEAREST)  # the columns
    np.testing.assert_array_equal(a.T[:, nearest_indices(src, dst)], ref)


def test_ground_truth_of_a_downsampled_camera_is_cv2s_nearest_resize(tmp_path):
    import cv2

    from ftgspp.diagnostics.motion import load_ground_truth

    model, is_obj = wall_and_object()
    full = tiny_scene(tmp_path, model, is_obj)
    (tmp_path / "gt" / "transient").mkdir()
    np.save(tmp_path / "gt" / "transient" / "cam00.npy", np.load(tmp_path / "gt" / "objects" / "cam00.npy") > 0)
    for factor in (0.5, 0.37):
        small = Scene(name="tiny", root=tmp_path, cameras=[full.cameras[0].scaled(factor)], frame_ids=np.array([1, 3]),
                      fps=FPS, train_ids=[0], test_ids=[0], decode=full.decode, ground_truth=full.ground_truth)
        gt = load_ground_truth(small, 0)
        cam = small.cameras[0]
        for name, field in (("depth", gt.depth), ("flow3d", gt.flow3d), ("objects", gt.objects),
                            ("transient", gt.transient)):
            saved = np.load(tmp_path / "gt" / name / "cam00.npy")[[1, 3]]
            ref = np.stack([cv2.resize(f.astype(np.float32), (cam.width, cam.height), interpolation=cv2.INTER_NEAREST)
                            for f in saved])  # the loader's way before the gather: float32 frames, resized
            ref = ref > 0 if name == "transient" else ref.astype(field.dtype)
            assert field.shape == ref.shape == (2, cam.height, cam.width, *saved.shape[3:]), (name, factor)
            assert np.array_equal(field, ref), (name, factor)


def test_held_out_renders_are_made_once_for_evaluation_and_diagnostics(tmp_path, monkeypatch):
    """Evaluation, LPIPS and diagnostics share the held-out renders: each view is rendered
    once, and every number is the one each computes with renders of its own."""
    import dataclasses

    import ftgspp.evaluate as ev

    model, is_obj = wall_and_object()
    one = tiny_scene(tmp_path, model, is_obj)  # two cameras: the held-out one is not the training one
    aside = dataclasses.replace(one.cameras[0], name="cam01", T=np.array([0.3, -0.2, 0.0]))
    scene = dataclasses.replace(one, cameras=[aside, one.cameras[0]], train_ids=[0], test_ids=[1])
    cfg = TrainConfig()
    cfg.model.sh_degree = 0
    alone, _ = ev.evaluate(model, scene, cfg, tmp_path / "alone")
    diag_alone = run_diagnostics(model, scene, cfg, tmp_path / "d_alone").metrics()
    calls = []
    real = ev.render_view
    monkeypatch.setattr(ev, "render_view", lambda *a, **k: calls.append(a[2]) or real(*a, **k))
    import ftgspp.diagnostics.diagnose as dg

    real_frames = dg.render_frames  # the figure's lifetime groups render subsets of the model: those may
    monkeypatch.setattr(dg, "render_frames",
                        lambda m, *a, **k: pytest.fail("rendered again") if m is model else real_frames(m, *a, **k))
    renders = ev.HeldOutRenders(model, scene, cfg)
    reused, _ = ev.evaluate(model, scene, cfg, tmp_path / "reused", renders=renders)
    ev._score(renders, ["psnr"], None, None, 0)  # a second pass, as evaluate_lpips makes
    diag = run_diagnostics(model, scene, cfg, tmp_path / "d_reused", renders=renders).metrics()
    assert sorted(calls) == sorted(float(t) for t in scene.times)  # one render per held-out frame
    assert reused == alone
    np.testing.assert_equal(diag, diag_alone)
    for d in ("d_alone", "d_reused"):  # the figures' render too (velocity map)
        assert (tmp_path / d / "velocity_map.png").is_file()
    assert (tmp_path / "d_alone" / "velocity_map.png").read_bytes() == (tmp_path / "d_reused" / "velocity_map.png").read_bytes()
    # renders at other settings, or of another scene or model, are not reused
    assert not renders.matches(model, scene, 3, renders.background, cfg.backend)
    assert not renders.matches(model, scene, 0, torch.ones(3), cfg.backend)
    assert not renders.matches(model, one, 0, renders.background, cfg.backend)
    with pytest.raises(ValueError, match="another model"):
        ev.evaluate(wall_and_object()[0], scene, cfg, tmp_path / "other", renders=renders)
    tight = ev.HeldOutRenders(model, scene, cfg, max_bytes=1)  # too large to keep: rendered on every call
    tight.image(0, 0), tight.image(0, 0)
    assert not tight.keep and len(calls) == scene.n_frames + 2
