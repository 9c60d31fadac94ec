"""gpja.apply.animate: interpolated positions, sequences, rendered frames, tiling and the video (MP4 or GIF)."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from gpja.apply import animate as A
from gpja.camera import framing_camera
from gpja.errors import InputError
from gpja.lighting import uniform_sh
from tests.tolerances import EXACT_F64

#: A constant float32 texture under uniform white SH (shading factor 1 up to float32 rounding; measured 7e-8).
CONSTANT_TEXTURE_RENDER = 1e-5
#: Antialiased coverage summed over an image vs the surface's exactly projected area, relative (measured 0.2 %).
COVERAGE_VS_PROJECTED_AREA = 0.01
#: H.264 (crf 10, yuv420p) of a smooth image read back, mean absolute error, [0, 1] units.
VIDEO_MEAN_ABS = 0.02
#: The same for the GIF fallback (256-colour palette per frame), mean absolute error, [0, 1] units.
GIF_MEAN_ABS = 0.03

ALBEDO = np.array([0.2, 0.5, 0.7], dtype=np.float32)
SQUARE_MM = 50.0  # half side


def textured_square(n: int = 11):
    """A 100 x 100 mm square in the z = 0 plane facing +Z, an n x n vertex grid (2 (n-1)^2 faces), UVs = x, y.

    Returns V (n^2, 3) float64 mm, F (m, 3) int64 (shared by the UVs), UV (n^2, 2) float64, corners (4, 3).
    """
    x, y = np.meshgrid(np.linspace(-SQUARE_MM, SQUARE_MM, n), np.linspace(-SQUARE_MM, SQUARE_MM, n))
    V = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    UV = (V[:, :2] + SQUARE_MM) / (2 * SQUARE_MM)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    s = SQUARE_MM
    corners = np.array([[-s, -s, 0.0], [s, -s, 0.0], [s, s, 0.0], [-s, s, 0.0]])
    return V, F, UV, corners


def projected_area(camera, corners: np.ndarray) -> float:
    """Pixel area of a planar quad's image (a pinhole camera maps it to a quad: shoelace formula)."""
    uv = camera.project(corners)[0]
    return 0.5 * abs(float(np.dot(uv[:, 0], np.roll(uv[:, 1], 1)) - np.dot(uv[:, 1], np.roll(uv[:, 0], 1))))


# --- interpolate ----------------------------------------------------------------------------------------------

def test_interpolate_endpoints_are_bitwise_exact():
    rng = np.random.default_rng(0)
    a = rng.normal(scale=80.0, size=(500, 3)) * 10.0 ** rng.integers(-8, 8, size=(500, 1))
    b = rng.normal(scale=80.0, size=(500, 3)) * 10.0 ** rng.integers(-8, 8, size=(500, 1))
    a[0, 0], b[0, 1] = -0.0, -0.0  # (1 - t) a + t b would turn these into +0.0
    at0, at1 = A.interpolate(a, b, 0.0), A.interpolate(a, b, 1)
    np.testing.assert_array_equal(at0.view(np.uint64), a.view(np.uint64))
    np.testing.assert_array_equal(at1.view(np.uint64), b.view(np.uint64))
    assert at0 is not a and at1 is not b and at0.dtype == np.float64


def test_interpolate_midpoint_and_quarter_are_analytic():
    a = np.array([[0.0, 10.0, -4.0], [2.0, 2.0, 2.0]])
    b = np.array([[8.0, -10.0, 4.0], [6.0, 2.0, -2.0]])
    np.testing.assert_allclose(A.interpolate(a, b, 0.5), [[4.0, 0.0, 0.0], [4.0, 2.0, 0.0]], atol=EXACT_F64)
    np.testing.assert_allclose(A.interpolate(a, b, 0.25), a + 0.25 * (b - a), atol=EXACT_F64)
    np.testing.assert_allclose(A.interpolate(a, b, 1.5), a + 1.5 * (b - a), atol=EXACT_F64)  # extrapolates


@pytest.mark.parametrize("b, t", [(np.zeros((4, 3)), 0.5), (np.zeros((3, 2)), 0.5), (np.zeros((3, 3)), np.nan)])
def test_interpolate_rejects_mismatched_arrays_and_bad_t(b, t):
    with pytest.raises(ValueError):
        A.interpolate(np.zeros((3, 3)), b, t)


# --- sequence_positions ---------------------------------------------------------------------------------------

def expression_positions(n: int = 20) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(1)
    return {name: rng.normal(scale=50.0, size=(n, 3)) for name in ("1_neutral", "2_smile", "3_mouth_stretch")}


def test_sequence_frame_count_labels_and_keyframes():
    positions = expression_positions()
    sequence = ["1_neutral", "2_smile", "3_mouth_stretch", "1_neutral"]
    frames, labels = A.sequence_positions(positions, sequence, 4)
    assert len(frames) == len(labels) == 3 * 4 + 1
    assert labels[:5] == [("1_neutral", "2_smile", 0.0), ("1_neutral", "2_smile", 0.25),
                          ("1_neutral", "2_smile", 0.5), ("1_neutral", "2_smile", 0.75),
                          ("2_smile", "3_mouth_stretch", 0.0)]
    assert labels[-1] == ("3_mouth_stretch", "1_neutral", 1.0)
    for frame, (start, end, t) in zip(frames, labels):
        assert frame.shape == (20, 3) and frame.dtype == np.float64
        np.testing.assert_array_equal(frame, A.interpolate(positions[start], positions[end], t))
    # keyframes are the expressions bit for bit, and the loop closes on the first one
    for i, name in zip((0, 4, 8, 12), sequence):
        np.testing.assert_array_equal(frames[i], positions[name])
    np.testing.assert_allclose(frames[2], (positions["1_neutral"] + positions["2_smile"]) / 2, atol=EXACT_F64)


def test_sequence_with_one_frame_per_transition_is_the_keyframes():
    positions = expression_positions()
    frames, labels = A.sequence_positions(positions, ["2_smile", "1_neutral"], 1)
    assert labels == [("2_smile", "1_neutral", 0.0), ("2_smile", "1_neutral", 1.0)]
    np.testing.assert_array_equal(frames[0], positions["2_smile"])
    np.testing.assert_array_equal(frames[1], positions["1_neutral"])
    frames[0][0, 0] = 1e6  # frames are copies, not views of the input
    assert positions["2_smile"][0, 0] != 1e6


@pytest.mark.parametrize("sequence, k, edit, match", [
    (["1_neutral", "9_missing", "2_smile"], 3, None, "9_missing"),
    (["1_neutral"], 3, None, "at least 2"),
    ([], 3, None, "at least 2"),
    (["1_neutral", "2_smile"], 0, None, "integer >= 1"),
    (["1_neutral", "2_smile"], 2.5, None, "integer >= 1"),
    (["1_neutral", "2_smile", "3_mouth_stretch"], 2, ("3_mouth_stretch", np.zeros((19, 3))), "'3_mouth_stretch'"),
    (["1_neutral", "2_smile"], 2, ("2_smile", np.zeros((20, 2))), "'2_smile'"),
])
def test_sequence_bad_inputs_raise_input_errors_naming_the_problem(sequence, k, edit, match):
    positions = expression_positions()
    if edit is not None:
        positions[edit[0]] = edit[1]
    with pytest.raises(InputError, match=match) as info:
        A.sequence_positions(positions, sequence, k, source="animate.sequence")
    assert info.value.path == "animate.sequence"


# --- render_frames and tile_views -----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def square_scene():
    V, F, UV, corners = textured_square()
    cameras = [framing_camera(V * 1.4, 48, yaw_deg=0.0, name="front"),
               framing_camera(V * 1.4, 48, yaw_deg=30.0, name="left")]
    texture = np.broadcast_to(ALBEDO, (8, 8, 3)).copy()
    return V, F, UV, corners, cameras, texture


def test_render_frames_shows_the_albedo_on_the_background_with_exact_coverage(square_scene):
    V, F, UV, corners, cameras, texture = square_scene
    grown = V * [1.2, 1.2, 1.0]
    frames, _ = A.sequence_positions({"a": V, "b": grown}, ["a", "b"], 2)  # t = 0, 0.5, 1
    white = A.render_frames(frames, F, UV, F, texture, cameras, uniform_sh(), progress=False, background=1.0)
    black = A.render_frames(frames, F, UV, F, texture, cameras, uniform_sh(), progress=False, background=0.0)
    assert white.shape == (3, 2, 48, 48, 3) and white.dtype == np.float32
    assert white.min() >= 0.0 and white.max() <= 1.0
    # every pixel is albedo * c + background * (1 - c) with one coverage c for all channels
    coverage = 1.0 - (white - black)
    np.testing.assert_allclose(coverage[..., 1:], coverage[..., :1].repeat(2, axis=-1), atol=CONSTANT_TEXTURE_RENDER)
    np.testing.assert_allclose(black, ALBEDO * coverage, atol=CONSTANT_TEXTURE_RENDER)
    full = coverage[..., 0] > 1.0 - CONSTANT_TEXTURE_RENDER
    assert full[:, 0].mean() > 0.2 and full[:, 1].mean() > 0.2  # both views see the square
    np.testing.assert_allclose(white[full], np.broadcast_to(ALBEDO, white[full].shape), atol=CONSTANT_TEXTURE_RENDER)
    assert np.all(white[coverage[..., 0] == 0.0] == 1.0)  # empty pixels are exactly the background
    # the antialiased coverage adds up to the square's projected area, frame by frame (it grows by 1.1^2, 1.2^2)
    for i, scale in enumerate((1.0, 1.1, 1.2)):
        for j, cam in enumerate(cameras):
            area = projected_area(cam, corners * [scale, scale, 1.0])
            assert coverage[i, j, ..., 0].sum() == pytest.approx(area, rel=COVERAGE_VS_PROJECTED_AREA)


def test_render_frames_uses_the_given_backend_and_an_rgb_background(square_scene):
    from gpja.render import render_views

    V, F, UV, _, cameras, texture = square_scene
    calls = []

    def spy(*args, **kwargs):
        calls.append(len(args[2]))
        return render_views(*args, **kwargs)

    out = A.render_frames([V, V + [0.0, 0.0, 5.0]], F, UV, F, texture, cameras[:1], uniform_sh(), render=spy,
                          progress=True, background=(0.0, 0.5, 1.0))
    assert calls == [1, 1]
    np.testing.assert_array_equal(out[0, 0, 0, 0], [0.0, 0.5, 1.0])  # a corner is empty
    with pytest.raises(ValueError, match="background"):
        A.render_frames([V], F, UV, F, texture, cameras, uniform_sh(), progress=False, background=2.0)
    with pytest.raises(ValueError, match="image size"):
        A.render_frames([V], F, UV, F, texture, [cameras[0], cameras[1].resized(32, 32)], uniform_sh(),
                        progress=False)


def test_tile_views_puts_the_cameras_side_by_side():
    views = np.random.default_rng(2).random((4, 3, 5, 7, 3)).astype(np.float32)
    tiled = A.tile_views(views)
    assert tiled.shape == (4, 5, 21, 3) and tiled.dtype == np.float32
    for c in range(3):
        np.testing.assert_array_equal(tiled[:, :, 7 * c: 7 * (c + 1)], views[:, c])
    with pytest.raises(ValueError):
        A.tile_views(views[0])


# --- write_video ----------------------------------------------------------------------------------------------

def smooth_frames(n: int = 5, height: int = 33, width: int = 47) -> np.ndarray:
    """(n, H, W, 3) float32 in [0, 1]: a smooth pattern that moves (and brightens) frame by frame."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float32)
    return np.stack([np.stack([0.5 + 0.3 * np.sin((u + 3 * i) / 7), 0.4 + 0.3 * np.cos(v / 6) + 0.02 * i,
                               0.5 + 0.2 * np.sin((u + v) / 9)], axis=-1) for i in range(n)])


def read_mp4(path) -> tuple[np.ndarray, dict]:
    import imageio.v2 as imageio

    with imageio.get_reader(str(path), format="FFMPEG") as reader:
        return np.stack(list(reader.iter_data())), reader.get_meta_data()


def test_write_video_writes_an_h264_mp4_that_reads_back(tmp_path):
    frames = smooth_frames()  # odd sides: padded to 34 x 48
    path = A.write_video(frames, tmp_path / "out" / "anim.mp4", fps=12)
    assert path == tmp_path / "out" / "anim.mp4" and path.is_file()
    assert [p.name for p in path.parent.iterdir()] == ["anim.mp4"]  # no temporary file left
    back, meta = read_mp4(path)
    assert back.shape == (5, 34, 48, 3)
    assert meta["codec"] == "h264" and meta["pix_fmt"].startswith("yuv420p") and meta["fps"] == 12
    assert np.abs(back[:, :33, :47] / 255.0 - frames).mean() < VIDEO_MEAN_ABS
    # deterministic given the frames
    first = path.read_bytes()
    A.write_video(frames, path, fps=12)
    assert path.read_bytes() == first


def test_write_video_falls_back_to_a_gif_without_ffmpeg(tmp_path, monkeypatch):
    import imageio_ffmpeg
    from PIL import Image, ImageSequence

    def no_ffmpeg():
        raise RuntimeError("No ffmpeg exe could be found")

    monkeypatch.setattr(imageio_ffmpeg, "get_ffmpeg_exe", no_ffmpeg)
    frames = smooth_frames()
    with pytest.warns(RuntimeWarning, match="no ffmpeg.*No ffmpeg exe could be found"):
        path = A.write_video(frames, tmp_path / "anim.mp4", fps=10)
    assert path == tmp_path / "anim.gif" and not (tmp_path / "anim.mp4").exists()
    with Image.open(path) as gif:
        assert gif.n_frames == 5 and gif.size == (47, 33) and gif.info["duration"] == 100
        back = np.stack([np.asarray(f.convert("RGB")) for f in ImageSequence.Iterator(gif)])
    assert np.abs(back / 255.0 - frames).mean() < GIF_MEAN_ABS


def test_write_video_falls_back_without_the_imageio_ffmpeg_package(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # import fails
    with pytest.warns(RuntimeWarning, match="imageio-ffmpeg package is not installed"):
        path = A.write_video(smooth_frames(2, 8, 8), tmp_path / "a.mp4")
    assert path.suffix == ".gif" and path.is_file()


@pytest.mark.parametrize("frames, name, fps, error", [
    (smooth_frames(2, 8, 8), "a.gif", 24, InputError),
    (smooth_frames(2, 8, 8), "a.mp4", 0, ValueError),
    (np.zeros((0, 8, 8, 3)), "a.mp4", 24, ValueError),
    (np.full((1, 8, 8, 3), np.nan), "a.mp4", 24, ValueError),
])
def test_write_video_rejects_bad_arguments(tmp_path, frames, name, fps, error):
    with pytest.raises(error):
        A.write_video(frames, tmp_path / name, fps=fps)
    assert not any(tmp_path.iterdir())
