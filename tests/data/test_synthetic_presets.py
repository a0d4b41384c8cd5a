"""The synthetic presets for the events real captures have (transient objects, occlusion, a
flame, exposure drift, long and short clips, a closed window): each one's ground truth is
checked against what the renders show, and the same seed gives the same bytes."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from ftgspp.data.synthetic.build import generate, main
from ftgspp.data.synthetic.presets import PRESETS, resolve_config

SMALL = dict(layout="easyvolcap", n_cameras=3, width=80, height=60)


def load_json(path: Path) -> dict:
    return json.loads(path.read_text())


def frames(scene: Path, cam: str = "cam00") -> np.ndarray:
    paths = sorted((scene / "images" / cam).glob("*.png"))
    return np.stack([cv2.imread(str(p))[..., ::-1] for p in paths]).astype(np.float64) / 255.0


@pytest.fixture(scope="module")
def transient(tmp_path_factory) -> Path:
    return generate(tmp_path_factory.mktemp("synth") / "transient", preset="transient", n_frames=20, noise=0.0,
                    **SMALL)


def test_every_preset_is_listed_and_resolves():
    for name in ("transient", "occlusion", "exposure_drift", "long_slow", "short_fast", "closed_window", "flame",
                 "plain"):
        assert name in PRESETS
        resolve_config(name)
    assert resolve_config("long_slow").n_frames / resolve_config("long_slow").fps >= 3.0  # a 3-10 s clip


def test_transient_masks_follow_the_objects_and_the_renders(transient):
    objects = load_json(transient / "gt" / "objects.json")
    fps = objects["fps"]
    kinds = {o["name"]: o for o in objects["objects"]}
    assert {"transient_0", "transient_1"} <= set(kinds)
    labels = [o["label"] for o in objects["objects"] if o["role"] == "transient"]
    obj = np.load(transient / "gt" / "objects" / "cam00.npy")
    mask = np.load(transient / "gt" / "transient" / "cam00.npy").astype(bool)
    assert np.array_equal(mask, np.isin(obj, labels))
    for o in objects["objects"]:
        if o["role"] != "transient":
            assert o["exists"] == [None, None] and all(o["present"])
            continue
        start, end = o["exists"]
        present = [start <= f / fps < end for f in range(len(o["present"]))]
        assert o["present"] == present and 0 < sum(present) < len(present)
        counts = (obj == o["label"]).sum(axis=(1, 2))
        assert counts.tolist() == o["visible_pixels"]["cam00"]
        assert not counts[~np.array(present)].any()  # never drawn while absent
    # the pixels of a transient object change when it appears; static ones do not
    rgb = frames(transient)
    first = kinds["transient_0"]["present"].index(True)
    appeared = mask[first] & (obj[first - 1] == 0)
    assert appeared.sum() > 10
    change = np.abs(rgb[first] - rgb[first - 1]).mean(axis=-1)
    still = (obj[first] == 0) & (obj[first - 1] == 0)
    assert change[appeared].mean() > 0.05 > 20 * change[still].mean()


def test_same_seed_gives_the_same_bytes(transient, tmp_path):
    again = generate(tmp_path / "again", preset="transient", n_frames=20, noise=0.0, workers=1, **SMALL)
    files = sorted(p.relative_to(transient) for p in transient.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    for rel in files:
        assert (transient / rel).read_bytes() == (again / rel).read_bytes(), rel


def test_the_occluded_ball_disappears_behind_the_crate(tmp_path):
    scene = generate(tmp_path / "occ", preset="occlusion", n_frames=16, **SMALL)
    ball = next(o for o in load_json(scene / "gt" / "objects.json")["objects"] if o["name"] == "ball_occluded")
    counts = np.array(ball["visible_pixels"]["cam00"])
    assert all(ball["present"]) and counts[0] > 20 and counts[-1] > 20
    hidden = counts < 0.1 * counts.max()
    assert hidden.any() and not hidden[0] and not hidden[-1]  # visible, then behind the crate, then visible
    # hidden by something nearer: where the ball would be, the depth is the crate's
    traj = next(o for o in load_json(scene / "gt" / "trajectories.json")["objects"] if o["name"] == "ball_occluded")
    cam = load_json(scene / "gt" / "scene.json")["cameras"][0]
    f = int(np.argmax(hidden))
    X = np.array(traj["position"][f])
    x_cam = np.array(cam["R"]) @ X + np.array(cam["T"]).ravel()
    u, v, _ = np.array(cam["K"]) @ (x_cam / x_cam[2])
    depth = np.load(scene / "gt" / "depth" / "cam00.npy")[f]
    assert depth[int(v), int(u)] < x_cam[2] - 0.3


def test_exposure_drift_is_the_recorded_gain_per_frame(tmp_path):
    kw = dict(n_frames=8, noise=0.0, color_shift=0.0, **SMALL)
    plain = generate(tmp_path / "plain", preset="studio", **kw)
    drift = generate(tmp_path / "drift", preset="exposure_drift", **kw)
    gains = np.array(load_json(drift / "gt" / "color_transforms.json")["cameras"]["cam01"]["gain"])  # [F, 3]
    assert gains.shape == (8, 3) and np.ptp(gains, axis=0).max() > 0.005  # it drifts
    assert np.abs(np.log(gains)).max() <= 0.15 + 0.05 + 1e-9  # within the stated strength
    a, b = frames(plain, "cam01"), frames(drift, "cam01")
    for f in range(8):
        ok = np.all((a[f] > 0.05) & (b[f] < 0.98), axis=-1)
        ratio = (a[f][ok] * b[f][ok]).sum(axis=0) / (a[f][ok] ** 2).sum(axis=0)  # least-squares gain per channel
        assert np.allclose(ratio, gains[f], atol=6e-3), f


def test_long_slow_and_short_fast_differ_in_duration_and_speed(tmp_path):
    long = generate(tmp_path / "long", preset="long_slow", n_frames=12, fps=3.0, **SMALL)  # 4 s, few frames
    short = generate(tmp_path / "short", preset="short_fast", n_frames=6, **SMALL)
    speed = {}
    for name, scene in (("long", long), ("short", short)):
        meta = load_json(scene / "gt" / "scene.json")
        traj = load_json(scene / "gt" / "trajectories.json")
        speed[name] = np.mean([np.linalg.norm(v) for o in traj["objects"] for v in o["velocity"]])
        assert meta["fps"] == (3.0 if name == "long" else 30.0)
    assert speed["short"] > 5 * speed["long"]


def test_closed_window_has_no_far_backdrop(tmp_path):
    kw = dict(n_frames=1, **SMALL)
    open_ = np.load(generate(tmp_path / "open", preset="studio", **kw) / "gt" / "depth" / "cam00.npy")
    closed_scene = generate(tmp_path / "closed", preset="closed_window", **kw)
    closed = np.load(closed_scene / "gt" / "depth" / "cam00.npy")
    assert open_.max() > 21.7 > 10.0 > closed.max()  # the indoor prior's far plane lies between
    window = open_ > 20  # elsewhere the room is the same
    assert window.any() and np.array_equal(open_[~window], closed[~window])


def test_the_flame_changes_colour_but_not_shape(tmp_path):
    scene = generate(tmp_path / "flame", preset="flame", n_frames=4, noise=0.0, **SMALL)
    flame = next(o for o in load_json(scene / "gt" / "objects.json")["objects"] if o["role"] == "flame")
    obj = np.load(scene / "gt" / "objects" / "cam00.npy")
    on = obj == flame["label"]
    silhouette = on.any(axis=0)
    in_front = (obj != 0) & ~on  # a moving ball may pass in front of it
    assert on.any() and np.array_equal(on, silhouette[None] & ~in_front)  # fixed geometry
    assert not np.load(scene / "gt" / "flow3d" / "cam00.npy")[on].astype(float).any()  # no motion
    rgb = frames(scene)
    change = np.abs(np.diff(rgb, axis=0)).mean(axis=-1)  # [F-1, H, W]
    still = (obj == 0).all(axis=0)
    assert change[:, on.all(axis=0)].mean() > 0.02 > 10 * change[:, still].mean()


def test_cli_options_and_bad_values(tmp_path, capsys):
    assert main(["--out", str(tmp_path / "a"), "--preset", "studio", "--transients", "1", "--frames", "6",
                 "--fps", "3", "--cameras", "2", "--width", "32", "--height", "24"]) == 0
    meta = load_json(tmp_path / "a" / "gt" / "scene.json")
    assert meta["params"]["transients"] == 1 and meta["fps"] == 3.0
    assert "window" not in meta["params"]  # at their defaults, the new knobs are not written
    assert main(["--out", str(tmp_path / "b"), "--transients", "3"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--transients" in err[0]


def test_plain_is_the_static_room_with_little_texture_detail(tmp_path, capsys):
    kw = dict(n_frames=3, noise=0.0, **SMALL)
    static, plain = (generate(tmp_path / n, preset=n, **kw) for n in ("static", "plain"))
    for name in ("depth", "objects"):  # the same geometry
        assert np.array_equal(np.load(static / "gt" / name / "cam01.npy"), np.load(plain / "gt" / name / "cam01.npy"))
    a, b = frames(static, "cam01"), frames(plain, "cam01")
    assert np.abs(np.diff(b, axis=0)).max() < 1e-9  # nothing moves

    def detail(img: np.ndarray) -> float:  # high-frequency energy: mean |Laplacian| of the luminance
        return float(np.abs(cv2.Laplacian(img.mean(axis=-1), cv2.CV_64F)).mean())

    assert detail(b[0]) < 0.5 * detail(a[0])
    assert main(["--out", str(tmp_path / "bad"), "--preset", "plain", "--detail", "1.5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--detail" in err[0]
