"""The Google Immersive loader: the publisher's lens model, undistortion, frames, caching.

Fisheye frames are rendered by ``fixtures.py`` with the README's lens formula inverted by its
own Newton steps; the loader undistorts with OpenCV. A straight 3D edge must come out straight
and where the loaded pinhole camera projects it. Bad ``models.json``: ``test_loader_errors.py``.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from ftgspp.config import DataConfig
from ftgspp.data import immersive
from ftgspp.data.immersive import read_models
from ftgspp.data.load import detect_format, load_scene

try:  # tests/ importable as a package
    from tests.data import fixtures as fx
except ImportError:  # pytest's default "prepend" import mode puts this folder on sys.path
    import fixtures as fx  # type: ignore[no-redef]

CENTERS = {"camera_0002": (0.4, 0.1, -4.0), "camera_0001": (0.0, 0.0, -4.0)}  # listed out of order
EDGE_CAM = (-1.2, 0.0, 1.0), (0.1, 1.0, 0.05)  # the edge in camera_0001's coordinates: point / 4, direction
LEVEL = 130.0  # halfway between the fixture's dark (60) and bright (200) sides


def test_readme_worked_example_through_opencv_fisheye(tmp_path):
    (tmp_path / "models.json").write_text(json.dumps([fx.README_VIEW]))
    (cam,) = read_models(tmp_path / "models.json")
    uv, _ = cv2.fisheye.projectPoints(np.array([[fx.README_POINT]]), cv2.Rodrigues(cam.R)[0], cam.T, cam.K, cam.D)
    np.testing.assert_allclose(uv.reshape(2), fx.README_PIXEL, atol=1e-4)
    np.testing.assert_allclose(cam.pinhole().K[0, 0], 0.5 * fx.README_VIEW["focal_length"])


def _edge_world() -> tuple[np.ndarray, np.ndarray]:
    cam = fx.look_at_camera("camera_0001", CENTERS["camera_0001"])
    point, direction = np.array(EDGE_CAM[0]) * 4.0, np.array(EDGE_CAM[1])
    return cam.R.T @ (point - cam.T), cam.R.T @ direction


@pytest.fixture(scope="module")
def edge() -> tuple[list[dict], dict[str, np.ndarray]]:
    """The two views (the README lens at 160x120) and their fisheye frame of the edge."""
    views = [fx.immersive_view(name, c, (0.0, 0.0, 0.0), scale=1 / 16) for name, c in CENTERS.items()]
    return views, {v["name"]: fx.edge_frame(v, *_edge_world()) for v in views}


def _edge_scene(root, edge, n_frames=2, as_images=False):
    views, frames = edge
    return fx.write_immersive(root, {k: [f] * n_frames for k, f in frames.items()}, views, as_images=as_images)


def _crossings(grey: np.ndarray) -> np.ndarray:
    """Sub-pixel (x, y) where a row crosses LEVEL between the dark and the bright side (not where
    either meets black, outside the fisheye image)."""
    points = []
    for y, row in enumerate(grey.astype(np.float64)):
        d = row - LEVEL
        xs = [x for x in np.nonzero(d[:-1] * d[1:] < 0)[0] if 3 <= x < len(row) - 4
              and np.allclose(np.sort(row[[x - 3, x + 4]]), [60, 200], atol=20)]
        if len(xs) == 1:
            x = xs[0]
            points.append((x + d[x] / (d[x] - d[x + 1]), y))
    return np.array(points)


def _straightness(points: np.ndarray) -> float:
    """Largest distance (px) of ``points [N, 2]`` from their least-squares line x = a y + b."""
    a, b = np.polyfit(points[:, 1], points[:, 0], 1)
    return float(np.max(np.abs(points[:, 0] - (a * points[:, 1] + b)) / np.hypot(1.0, a)))


def test_straight_edge_stays_straight_and_lands_where_the_pinhole_projects_it(tmp_path, edge, capsys):
    root = _edge_scene(tmp_path / "s", edge)
    assert detect_format(root) == "immersive"
    scene = load_scene(DataConfig(path=str(root)))
    assert [c.name for c in scene.cameras] == ["camera_0001", "camera_0002"]  # sorted by name
    assert scene.test_ids == [0]  # camera_0001 held out by default
    cam = scene.cameras[0]
    assert cam.dist is None and (cam.width, cam.height) == (160, 120)

    raw = _crossings(edge[1]["camera_0001"][..., 0])
    undistorted = _crossings(scene.frames(0)[0, ..., 0])
    assert len(undistorted) > 40 and np.ptp(undistorted[:, 1]) > 40  # a long edge was measured
    point, direction = _edge_world()
    a, b = (cam.K @ (cam.R @ X + cam.T) for X in (point, point + direction))
    a, b = a[:2] / a[2], b[:2] / b[2]
    n = np.array([b[1] - a[1], a[0] - b[0]]) / np.linalg.norm(b - a)
    off_line = np.abs((undistorted - a) @ n)  # distance to the loaded camera's projection of the edge
    with capsys.disabled():
        print(f"\nstraight edge: fisheye {_straightness(raw):.2f} px from straight, undistorted "
              f"{_straightness(undistorted):.3f} px; max {off_line.max():.3f} px from its pinhole projection")
    assert _straightness(raw) > 3.0  # the raw fisheye edge is curved
    assert _straightness(undistorted) < 1.0
    assert off_line.max() < 1.0


def test_extracted_frames_and_videos_load_alike(tmp_path, edge):
    from_video = load_scene(DataConfig(path=str(_edge_scene(tmp_path / "v", edge, n_frames=3))))
    from_images = load_scene(DataConfig(path=str(_edge_scene(tmp_path / "i", edge, n_frames=3, as_images=True))))
    assert from_video.n_frames == from_images.n_frames == 3
    np.testing.assert_array_equal(from_video.frames(1), from_images.frames(1))  # lossless FFV1 vs PNG


def test_undistortion_maps_are_cached_beside_the_frames(tmp_path, edge, monkeypatch):
    root = _edge_scene(tmp_path / "s", edge, n_frames=3)
    load_scene(DataConfig(path=str(root), frame_end=2)).frames(1)
    maps = list((root / ".ftgspp_cache" / "undistort").glob("camera_0002-*.npy"))
    assert len(maps) == 1 and np.load(maps[0]).shape == (2, 120, 160)

    def no_maps(*args, **kwargs):
        raise AssertionError("undistortion maps recomputed")

    monkeypatch.setattr(immersive.FisheyeCamera, "undistort_maps", no_maps)
    assert load_scene(DataConfig(path=str(root), frame_start=1)).frames(1).shape == (2, 120, 160, 3)


@pytest.mark.parametrize("downsample", [1, 2])
def test_segment_and_downsample(tmp_path, edge, downsample):
    scene = load_scene(DataConfig(path=str(_edge_scene(tmp_path / "s", edge, n_frames=4)), frame_start=1, frame_end=3,
                                  downsample=downsample, test_cameras=["camera_0002"]))
    np.testing.assert_array_equal(scene.frame_ids, [1, 2])
    assert scene.test_ids == [1] and scene.frames(0).shape == (2, 120 // downsample, 160 // downsample, 3)
