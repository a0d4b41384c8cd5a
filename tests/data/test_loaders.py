"""Scene loaders (DyNeRF; EasyVolcap, with ENeRF-Outdoor's conventions): conventions, frame
ranges, caching (bad input: ``test_loader_errors.py``; Immersive: ``test_immersive.py``).

Scenes are tiny (32x24, 4 cameras, 6 frames) and written by ``fixtures.py``; each frame
shows a blob where the fixture's own camera model projects a moving 3D point, so marker
checks test the loaders' conventions independently of their code.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from ftgspp.config import DataConfig
from ftgspp.data.dynerf import cameras_from_poses_bounds
from ftgspp.data.load import detect_format, load_scene
from ftgspp.data.source import match_camera
from ftgspp.data.synthetic.formats import poses_bounds_row
from ftgspp.errors import InputError

try:  # tests/ importable as a package
    from tests.data import fixtures as fx
except ImportError:  # pytest's default "prepend" import mode puts this folder on sys.path
    import fixtures as fx  # type: ignore[no-redef]

MARKER_TOL_PX = 0.3  # blob centroid vs projection; a half-pixel convention slip is 0.5


def _load(root: Path, **kwargs) -> object:
    return load_scene(DataConfig(path=str(root), **kwargs))


def _projection(cam, X: np.ndarray) -> np.ndarray:
    x = cam.K @ (cam.R @ X + cam.T)
    return x[:2] / x[2]


def _assert_markers(scene) -> None:
    """Every loaded frame shows the marker where the loaded camera projects it at that time."""
    for c, cam in enumerate(scene.cameras):
        frames = scene.frames(c)
        assert frames.shape == (scene.n_frames, cam.height, cam.width, 3) and frames.dtype == np.uint8
        for k, t in enumerate(scene.times):
            found = fx.marker_centroid(frames[k])
            expected = _projection(cam, fx.marker_position(t))
            assert np.abs(found - expected).max() < MARKER_TOL_PX, (cam.name, k, found, expected)
        r, g, b = np.median(frames[0].reshape(-1, 3), axis=0)  # background colour: RGB, not BGR
        assert r > g > b


# --- format detection ------------------------------------------------------------------


def test_detect_format(tmp_path):
    assert detect_format(fx.write_dynerf(tmp_path / "a", n_frames=2)) == "dynerf"
    assert detect_format(fx.write_easyvolcap(tmp_path / "b", n_frames=2)) == "easyvolcap"
    (tmp_path / "c").mkdir()
    with pytest.raises(InputError, match="poses_bounds.npy.*intri.yml") as err:
        detect_format(tmp_path / "c")
    assert str(tmp_path / "c") in str(err.value)
    with pytest.raises(InputError, match="not found"):
        detect_format(tmp_path / "missing")


def test_forced_format_must_match_folder(tmp_path):
    root = fx.write_dynerf(tmp_path / "s", n_frames=2)
    assert load_scene(DataConfig(path=str(root), format="dynerf")).cameras[0].name == "cam00"
    with pytest.raises(InputError, match="intri.yml"):
        load_scene(DataConfig(path=str(root), format="easyvolcap"))


# --- conventions ------------------------------------------------------------------------


def test_dynerf_pose_round_trip(tmp_path):
    cams = fx.ring_cameras([f"cam{i:02d}" for i in range(4)])
    scene = _load(fx.write_dynerf(tmp_path / "s", cams, n_frames=2))
    assert [c.name for c in scene.cameras] == [c.name for c in cams]
    for want, got in zip(cams, scene.cameras):
        np.testing.assert_allclose(got.R, want.R, atol=1e-12)
        np.testing.assert_allclose(got.T, want.T, atol=1e-12)
        np.testing.assert_allclose(got.K, want.K, atol=1e-12)  # cx = W/2, cy = H/2
        assert (got.width, got.height) == (want.width, want.height)
    assert scene.near == pytest.approx(1.0) and scene.far == pytest.approx(12.0)


def test_dynerf_focal_follows_decoded_video_size(tmp_path):
    """H, W, focal in the file at twice the video size: focal is scaled to the video."""
    cams = fx.ring_cameras(["cam00", "cam01"])
    scene = _load(fx.write_dynerf(tmp_path / "s", cams, n_frames=2, hwf_scale=2.0))
    for want, got in zip(cams, scene.cameras):
        np.testing.assert_allclose(got.K, want.K, atol=1e-12)


def test_poses_bounds_writer_matches_stated_convention():
    """The writer ``ftgspp synth`` uses, against the fixtures' own rows and the loader."""
    cams = fx.ring_cameras(["cam00", "cam01", "cam02"])
    rows = np.stack([poses_bounds_row(cam, near, far) for cam, near, far in zip(cams, [1, 2, 3], [5, 6, 7])])
    np.testing.assert_allclose(rows, fx.llff_rows(cams, [1, 2, 3], [5, 6, 7]), atol=1e-12)
    back = cameras_from_poses_bounds(rows, [c.name for c in cams])
    np.testing.assert_allclose(back[1].R, cams[1].R, atol=1e-12)


@pytest.mark.parametrize("layout", ["dynerf", "easyvolcap"])
@pytest.mark.parametrize("downsample", [1, 2])
def test_marker_lands_where_loaded_camera_projects_it(tmp_path, layout, downsample):
    root = fx.write_scene(layout, tmp_path / "s", **(dict(ext=".jpg") if layout == "easyvolcap" else {}))
    _assert_markers(_load(root, downsample=downsample, frame_start=1, frame_end=5))


@pytest.mark.parametrize(
    "options", [dict(rotation="matrix"), dict(rotation="rodrigues", dist_key="dist", write_size=False)]
)
def test_easyvolcap_calibration_variants_round_trip(tmp_path, options):
    cams = fx.ring_cameras(["00", "01", "02"])
    scene = _load(fx.write_easyvolcap(tmp_path / "s", cams, n_frames=2, **options))
    for want, got in zip(cams, scene.cameras):
        np.testing.assert_allclose(got.R, want.R, atol=1e-9)
        np.testing.assert_allclose(got.T, want.T, atol=1e-12)
        np.testing.assert_allclose(got.K, want.K, atol=1e-12)
        assert (got.width, got.height) == (want.width, want.height)
    _assert_markers(scene)


def test_easyvolcap_distorted_frames_are_undistorted_with_same_K(tmp_path):
    dist = np.array([1.2, -0.2, 0.002, -0.003, 0.0])
    cams = fx.ring_cameras(["00", "01"]) + [
        fx.look_at_camera("02", (0.3, 0.2, -4.0), target=(1.0, -0.7, 0.1), dist=dist)
    ]
    root = fx.write_easyvolcap(tmp_path / "s", cams, n_frames=3)
    scene = _load(root)
    got = scene.cameras[2]
    assert got.dist is None
    np.testing.assert_allclose(got.K, cams[2].K)
    raw = cv2.cvtColor(cv2.imread(str(root / "images" / "02" / "000000.png")), cv2.COLOR_BGR2RGB)
    pinhole = _projection(got, fx.marker_position(0.0))
    assert np.abs(fx.marker_centroid(raw) - pinhole).max() > 0.8  # the raw frame is distorted
    _assert_markers(scene)


# --- frame range, downsampling, split -----------------------------------------------------


@pytest.mark.parametrize("layout", ["dynerf", "easyvolcap"])
def test_frame_range_and_times_in_seconds(tmp_path, layout):
    root = fx.write_scene(layout, tmp_path / "s", n_frames=6, fps=25.0)
    scene = _load(root, frame_start=2, frame_end=5)
    assert scene.fps == pytest.approx(25.0)  # dynerf: from the video; easyvolcap: scene.json
    np.testing.assert_array_equal(scene.frame_ids, [2, 3, 4])
    np.testing.assert_allclose(scene.times, np.array([2, 3, 4]) / 25.0)
    assert scene.frames(1).shape[0] == 3
    assert _load(root).n_frames == 6  # frame_end=None: everything every camera has


def test_easyvolcap_fps_defaults_to_30_or_comes_from_metadata(tmp_path):
    root = fx.write_easyvolcap(tmp_path / "s", n_frames=2)
    assert _load(root).fps == 30.0
    (root / "gt").mkdir()
    (root / "gt" / "scene.json").write_text('{"fps": 24, "layout": "easyvolcap"}')  # synthetic scenes
    assert _load(root).fps == 24.0


@pytest.mark.parametrize("layout", ["dynerf", "easyvolcap"])
def test_downsample_scales_cameras_and_frames_together(tmp_path, layout):
    root = fx.write_scene(layout, tmp_path / "s", n_frames=2)
    full, half = _load(root), _load(root, downsample=2)
    for a, b, c in zip(full.cameras, half.cameras, range(len(full.cameras))):
        assert (b.width, b.height) == (a.width // 2, a.height // 2)
        assert b.K[0, 0] == pytest.approx(a.K[0, 0] / 2) and b.K[1, 1] == pytest.approx(a.K[1, 1] / 2)
        # the continuous image plane stays aligned: pixel centres move by half a pixel
        assert b.K[0, 2] == pytest.approx((a.K[0, 2] + 0.5) / 2 - 0.5)
        assert half.frames(c).shape == (2, b.height, b.width, 3)
        np.testing.assert_array_equal(b.R, a.R)


def test_drop_cameras_removes_camera_and_its_pose_row(tmp_path):
    cams = fx.ring_cameras([f"cam{i:02d}" for i in range(4)])
    scene = _load(fx.write_dynerf(tmp_path / "s", cams, n_frames=2), drop_cameras=["cam02"])
    assert [c.name for c in scene.cameras] == ["cam00", "cam01", "cam03"]
    np.testing.assert_allclose(scene.cameras[2].R, cams[3].R, atol=1e-12)  # row 3, not row 2
    assert scene.far == pytest.approx(12.0) and scene.train_ids == [1, 2] and scene.test_ids == [0]


def test_test_camera_matching():
    assert match_camera("cam00", ["00", "01"]) == 0
    assert match_camera("cam01", ["0", "1"]) == 1
    assert match_camera("01", ["cam00", "cam01"]) == 1
    assert match_camera("cam07", ["00", "01"]) is None
    assert match_camera("left", ["right", "left"]) == 1


def test_split_default_explicit_and_fallback(tmp_path):
    ev = fx.write_easyvolcap(tmp_path / "ev", n_frames=2)  # names 00..03
    scene = _load(ev)
    assert (scene.test_ids, scene.train_ids) == ([0], [1, 2, 3])
    scene = _load(ev, test_cameras=["cam02", "03"])
    assert (scene.test_ids, scene.train_ids) == ([2, 3], [0, 1])
    named = fx.write_easyvolcap(tmp_path / "named", fx.ring_cameras(["left", "mid", "right"]), n_frames=2)
    assert _load(named).test_ids == [0]  # default cam00 matches nothing: first camera
    with pytest.raises(InputError, match="data.test_cameras.*cam09"):
        _load(ev, test_cameras=["cam09"])
    with pytest.raises(InputError, match="data.test_cameras"):
        _load(ev, test_cameras=["00", "01", "02", "03"])


def test_scene_name_and_ground_truth_folder(tmp_path):
    root = fx.write_dynerf(tmp_path / "flame", n_frames=2)
    assert _load(root).name == "flame" and _load(root).ground_truth is None
    (root / "gt").mkdir()
    assert _load(root).ground_truth == root / "gt"


# --- cache --------------------------------------------------------------------------------


@pytest.mark.parametrize("layout", ["dynerf", "easyvolcap"])
def test_frames_cached_once_and_reused(tmp_path, layout):
    root = fx.write_scene(layout, tmp_path / "s", n_frames=3)
    scene = _load(root)
    assert scene.cache_dir.is_relative_to(root / ".ftgspp_cache")
    first = np.array(scene.frames(1))
    files = list(scene.cache_dir.glob("*.npy"))
    assert len(files) == 1
    mtime = files[0].stat().st_mtime_ns

    again = _load(root)
    assert again.cache_dir == scene.cache_dir

    def no_decode(cam: int) -> np.ndarray:
        raise AssertionError("decoded again instead of reading the cache")

    again.decode = no_decode
    np.testing.assert_array_equal(again.frames(1), first)
    assert files[0].stat().st_mtime_ns == mtime and len(list(scene.cache_dir.glob("*.npy"))) == 1


def test_concurrent_cache_writers_each_install_a_whole_file(tmp_path, monkeypatch):
    """Two runs fill the same frame cache at once: the second writes its file while the
    first is about to rename its own. Both read whole arrays (with one shared temporary
    name, the second truncated the first's file and a run died reading it)."""
    root = fx.write_scene("dynerf", tmp_path / "s", n_frames=3)
    first, second = _load(root), _load(root)
    expected = np.array(_load(root).decode(1))
    real_replace = os.replace
    rival_ran = []

    def replace_after_rival(src, dst):
        if not rival_ran:
            rival_ran.append(True)
            np.testing.assert_array_equal(second.frames(1), expected)
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", replace_after_rival)
    np.testing.assert_array_equal(first.frames(1), expected)
    assert rival_ran and len(list(first.cache_dir.glob("*.npy"))) == 1
    assert not list(first.cache_dir.glob("*.tmp"))  # no temporary file left behind


def test_cache_dir_option_and_stale_cache(tmp_path):
    a = fx.write_dynerf(tmp_path / "a" / "scene", n_frames=2)
    b = fx.write_dynerf(tmp_path / "b" / "scene", fx.ring_cameras(["cam00", "cam01"]), n_frames=2)
    sa = _load(a, cache_dir=str(tmp_path / "cache"))
    sb = _load(b, cache_dir=str(tmp_path / "cache"))
    assert sa.cache_dir.parent == tmp_path / "cache"
    assert sa.cache_dir != sb.cache_dir  # same scene name, different scenes: separate caches
    sa.frames(0)
    os.utime(a / "cam00.mp4", ns=(1, 1))  # the video changed: its cache must not be reused
    assert _load(a, cache_dir=str(tmp_path / "cache")).cache_dir != sa.cache_dir


# --- ENeRF-Outdoor, and the dataset configs --------------------------------------------------------


def test_enerf_outdoor_layout_with_distortion_loads(tmp_path):
    """EasyMocap-style yml (``dist_NN``, no image size), cameras 00..04, JPEGs, extra folders."""
    dists = [[-0.25, 0.07, 8e-4, -6e-4, 0.0], [-0.2, 0.05, 0.0, 0.0, 0.01], [-0.2, 0.05, 0.0, 0.0, 0.01],
             [-0.25, 0.07, 8e-4, -6e-4, 0.0], [-0.5, 0.2, 0.0, 0.0]]  # 04: strong, and 4 coefficients
    cams = fx.ring_cameras([f"{i:02d}" for i in range(4)]) + [fx.look_at_camera("04", (0.3, 0.2, -4.0), (1, -0.7, 0.1))]
    cams = [replace(c, dist=np.array(d)) for c, d in zip(cams, dists)]
    root = fx.write_easyvolcap(tmp_path / "actor1_4", cams, n_frames=4, ext=".jpg", dist_key="dist", write_size=False)
    for extra in ("bkgd", "bgmtv2/00", "vhull"):
        (root / extra).mkdir(parents=True)
    scene = _load(root, frame_end=3)
    assert [c.name for c in scene.cameras] == ["00", "01", "02", "03", "04"] and scene.test_ids == [0]
    assert all(c.dist is None for c in scene.cameras)
    for got, want in zip(scene.cameras, cams):
        np.testing.assert_allclose(got.K, want.K)  # undistorted keeping K (ENeRF's cv2.undistort)
    raw = cv2.cvtColor(cv2.imread(str(root / "images" / "04" / "000000.jpg")), cv2.COLOR_BGR2RGB)
    assert np.abs(fx.marker_centroid(raw) - _projection(scene.cameras[4], fx.marker_position(0.0))).max() > 0.5
    _assert_markers(scene)
    assert _load(root, test_cameras=["03"]).test_ids == [3]


@pytest.mark.parametrize(
    "group, want",
    [("immersive", dict(format="immersive", test_cameras=["camera_0001"], frame_end=50, downsample=2)),
     ("enerf_outdoor", dict(format="easyvolcap", test_cameras=["17"], frame_end=150))],
)
def test_dataset_configs_compose(group, want):
    from harness.spec.schema import compose, to_train_config

    cfg = to_train_config(compose([f"data={group}", "data.path=/data/x"])).data
    assert {k: getattr(cfg, k) for k in want} == want
