from __future__ import annotations

import csv
import os
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from spotnav import files
from spotnav.errors import SpotnavError
from spotnav.files import (
    POSES_COLUMNS,
    Frame,
    ImageReadError,
    PosesWriter,
    SequenceWriter,
    image_size,
    iter_frames,
    pose_row,
    read_image,
    read_known_poses,
    read_opencv_camera,
    read_setup,
    setup_to_toml,
    write_image,
)
from spotnav.pose.estimate import PoseEstimate
from spotnav.setup.config import Bump, Instrument, Setup, SetupError, World, setup_from_toml


def test_rgb_round_trip(tmp_path: Path) -> None:
    rgb = np.zeros((8, 9, 3), np.uint8)
    rgb[..., 0] = 200  # red
    write_image(tmp_path / "a.png", rgb)
    back = read_image(tmp_path / "a.png")
    np.testing.assert_array_equal(back, rgb)


@pytest.mark.parametrize(
    ("array", "shape", "dtype"),
    [
        (np.full((6, 7), 40000, np.uint16), (6, 7), np.uint16),
        (np.full((6, 7), 40, np.uint8), (6, 7), np.uint8),
        (np.full((6, 7, 4), 40, np.uint8), (6, 7, 4), np.uint8),
    ],
)
def test_grey_16_bit_and_rgba_are_read(tmp_path: Path, array: np.ndarray, shape: tuple, dtype: type) -> None:
    cv2.imwrite(str(tmp_path / "x.png"), array)
    image = read_image(tmp_path / "x.png")
    assert image.shape == shape and image.dtype == dtype


def test_bad_images_raise_one_line_errors(tmp_path: Path) -> None:
    (tmp_path / "empty.png").write_bytes(b"")
    (tmp_path / "text.png").write_text("not an image")
    cv2.imwrite(str(tmp_path / "good.png"), np.full((64, 64, 3), 90, np.uint8))
    data = (tmp_path / "good.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    cases = {"missing.png": "no such file", "empty.png": "empty", "text.png": "not an image", "cut.png": "not an image"}
    for name, message in cases.items():
        with pytest.raises(ImageReadError, match=message) as error:
            read_image(tmp_path / name)
        assert name in str(error.value) and "\n" not in str(error.value)


def test_an_image_is_sized_from_its_header_before_it_is_decoded(tmp_path: Path) -> None:
    good = tmp_path / "good.png"
    cv2.imwrite(str(good), np.full((48, 64, 3), 90, np.uint8))
    assert image_size(good) == (64, 48)
    with pytest.raises(ImageReadError, match="image is 64x48 px, the setup's camera is 64x64 px") as error:
        read_image(good, expected_size=(64, 64))
    assert error.value.status == "wrong_size"
    assert read_image(good, expected_size=(64, 48)).shape == (48, 64, 3)
    with pytest.raises(ImageReadError, match="64x48 px would take more than") as error:
        read_image(good, max_bytes=8 * 64 * 48 - 1)
    assert error.value.status == "unreadable"


def test_poses_rows_are_on_disk_as_soon_as_they_are_written(tmp_path: Path) -> None:
    path = tmp_path / "poses.csv"
    with PosesWriter(path) as writer:
        writer.write(pose_row("a.png", PoseEstimate("no_spot", detail="none")))
        assert path.read_bytes().count(b"\n") == 2 and b"\r" not in path.read_bytes()
        assert writer.rows == 1


def test_read_setup_names_the_file(tmp_path: Path) -> None:
    with pytest.raises(SetupError, match="cannot read"):
        read_setup(tmp_path / "none.toml")
    (tmp_path / "bad.toml").write_text("[eye]\nradius_mm = -3\n")
    with pytest.raises(SetupError, match=r"bad\.toml: eye\.radius_mm"):
        read_setup(tmp_path / "bad.toml")


def test_poses_csv_has_the_contract_columns_first(tmp_path: Path) -> None:
    ok = PoseEstimate("ok", tip_in_eye=np.array([1.0, 2.0, 3.0]), axis=np.array([0.0, 0.0, -1.0]), spots=1)
    rows = [pose_row("a.png", ok, 12.0), pose_row("b.png", PoseEstimate("no_spot", detail="dark"))]
    with PosesWriter(tmp_path / "poses.csv") as writer:
        for row in rows:
            writer.write(row)
    with (tmp_path / "poses.csv").open() as handle:
        table = list(csv.DictReader(handle))
    assert list(table[0])[:8] == ["image", "status", "x_mm", "y_mm", "z_mm", "dir_x", "dir_y", "dir_z"]
    assert tuple(table[0]) == POSES_COLUMNS
    assert float(table[0]["z_mm"]) == 3.0 and table[0]["status"] == "ok"
    assert table[1]["x_mm"] == "" and table[1]["detail"] == "dark"


def test_setup_to_toml_round_trips() -> None:
    setups = [
        Setup(),
        Setup(
            world=World(eye_radius_mm=13.0, bumps=(Bump(1.0, -2.0),), surface="sphere"),
            instrument=Instrument(beam_count=3, edge_half_angle_deg=8.5, height_correction=1.03),
        ),
    ]
    for setup in setups:
        text = setup_to_toml(setup, "a header\nof two lines")
        assert text.startswith("# a header\n# of two lines\n")
        assert setup_from_toml(text) == setup


def test_read_known_poses(tmp_path: Path) -> None:
    (tmp_path / "known.csv").write_text(
        "image,x_mm,y_mm,z_mm,dir_x,dir_y,dir_z\na.png,1,2,4,0,0,-1\n/abs/b.png,0,0,5,0,0,-1\n"
    )
    first, second = read_known_poses(tmp_path / "known.csv")
    assert first.image == tmp_path / "a.png" and second.image == Path("/abs/b.png")
    np.testing.assert_array_equal(first.tip_in_eye, [1, 2, 4])
    np.testing.assert_array_equal(second.axis, [0, 0, -1])
    (tmp_path / "bad.csv").write_text("image,x_mm,y_mm,z_mm\na.png,1,two,4\n")
    with pytest.raises(SpotnavError, match="line 2"):
        read_known_poses(tmp_path / "bad.csv")
    with pytest.raises(SpotnavError, match="cannot read"):
        read_known_poses(tmp_path / "missing.csv")


def _clip(tmp_path: Path, count: int, shape: tuple[int, int] = (48, 64)) -> tuple[Path, list[np.ndarray]]:
    """An FFV1 clip of ``count`` noise frames of ``shape`` (rows, columns), and the frames."""
    rng = np.random.default_rng(3)
    frames = [rng.integers(0, 256, (*shape, 3), dtype=np.uint8) for _ in range(count)]
    with SequenceWriter(tmp_path / "clip.mkv", fps=30.0) as writer:
        for index, rgb in enumerate(frames):
            writer.write(index, rgb)
    return tmp_path / "clip.mkv", frames


@pytest.mark.parametrize("ring", [0, 2])
def test_video_frames_decode_exactly_and_a_ring_reuses_its_buffers(tmp_path: Path, ring: int) -> None:
    clip, frames = _clip(tmp_path, 4)
    decoded = []
    for frame in iter_frames(str(clip), ring=ring):
        np.testing.assert_array_equal(frame.pixels, frames[frame.index])  # lossless, as handed over
        decoded.append(frame.pixels)
    assert len(decoded) == 4
    assert (decoded[0] is decoded[2]) == (ring == 2) and decoded[0] is not decoded[1]


def _child_processes() -> set[str]:
    return {
        child
        for task in Path(f"/proc/{os.getpid()}/task").iterdir()
        for child in (task / "children").read_text().split()
    }


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads Linux's /proc")
def test_a_decoder_process_hands_over_every_frame_and_keeps_the_one_before(tmp_path: Path) -> None:
    clip, frames = _clip(tmp_path, 7)
    cores, before = os.sched_getaffinity(0), _child_processes()
    waited_on: list[np.ndarray] = []
    source = iter_frames(str(clip), ring=2, while_waiting=waited_on.append)
    handed: list[Frame] = []
    for index in range(7):
        asked, waits = time.perf_counter(), len(waited_on)
        frame = next(source)
        # Asked for 50 ms after the frame before, once the decoder had it: its latency starts when it is asked for.
        assert frame.index == index and asked <= frame.ready_s <= time.perf_counter() and frame.decode_ms > 0
        np.testing.assert_array_equal(frame.pixels, frames[index])  # lossless, as handed over
        assert all(pixels is handed[-1].pixels for pixels in waited_on[waits:])  # it rehearsed the frame before
        time.sleep(0.05)  # the decoder has decoded the next frame meanwhile, into a buffer of its own
        if handed:  # the frame before is not written over: a rehearsal reads it
            np.testing.assert_array_equal(handed[-1].pixels, frames[index - 1])
        assert len(os.sched_getaffinity(0)) == (1 if len(cores) > 1 else len(cores))  # this thread on one core
        assert len(_child_processes() - before) == (1 if len(cores) > 1 else 0)
        handed.append(frame)
    with pytest.raises(StopIteration):
        next(source)
    assert np.shares_memory(handed[0].pixels, handed[3].pixels) == (len(cores) > 1)  # a ring of three buffers
    assert not np.shares_memory(handed[0].pixels, handed[1].pixels)
    assert os.sched_getaffinity(0) == cores and _child_processes() == before


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads Linux's /proc")
def test_a_decoder_process_stops_with_its_reader_and_reports_its_failure(tmp_path: Path) -> None:
    clip, frames = _clip(tmp_path, 5)
    cores, before = os.sched_getaffinity(0), _child_processes()
    source = iter_frames(str(clip), ring=1, while_waiting=lambda pixels: None)
    np.testing.assert_array_equal(next(source).pixels, frames[0])
    source.close()
    assert os.sched_getaffinity(0) == cores and _child_processes() == before

    def failing(pixels: np.ndarray) -> None:
        raise RuntimeError("a rehearsal failed")

    # Frames that take milliseconds to decode: the next one is surely still being decoded when it is asked for,
    # and the rehearsal runs (a frame already there is handed over without one).
    slow, _ = _clip(tmp_path / "slow", 2, (1024, 1024))
    source = iter_frames(str(slow), ring=2, while_waiting=failing)
    next(source)
    with pytest.raises(RuntimeError, match="a rehearsal failed"):
        next(source)
    assert os.sched_getaffinity(0) == cores and _child_processes() == before
    source = iter_frames(str(clip), ring=2, while_waiting=lambda pixels: None)  # opened and checked here ...
    clip.unlink()  # ... then gone when the decoder opens it
    with pytest.raises(ImageReadError, match=r"clip\.mkv: the decoder process failed: .*no such file"):
        next(source)
    assert os.sched_getaffinity(0) == cores and _child_processes() == before
    with pytest.raises(ValueError, match="ring must be at least 1, got 0"):
        next(iter_frames(str(tmp_path), ring=0, while_waiting=lambda pixels: None))


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads Linux's /proc")
def test_without_shared_memory_or_a_second_core_a_video_is_decoded_in_this_thread(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    clip, frames = _clip(tmp_path, 3)

    def no_room(descriptor: int, offset: int, size: int) -> None:
        raise OSError(28, "No space left on device")

    before = _child_processes()
    for patch in [(os, "posix_fallocate", no_room), (os, "sched_getaffinity", lambda pid: {0})]:
        with monkeypatch.context() as patched:
            patched.setattr(*patch)
            for frame in iter_frames(str(clip), ring=2, while_waiting=lambda pixels: None):
                np.testing.assert_array_equal(frame.pixels, frames[frame.index])
                assert _child_processes() == before  # no decoder process


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads Linux's /proc")
def test_the_tracker_keeps_to_the_core_it_runs_on() -> None:
    # Two trackers on one machine each keep to the core the scheduler gave it, not both to the first one.
    cores = os.sched_getaffinity(0)
    try:
        for core in sorted(cores):
            os.sched_setaffinity(0, {core})
            assert files._current_core(cores) == core
    finally:
        os.sched_setaffinity(0, cores)
    assert files._current_core(set(range(10_000, 10_002))) == 10_000  # a core it may not run on: the first allowed
    own, others = files._split_cores()
    assert (len(own), own | others, own & others) == ((1, cores, set()) if len(cores) > 1 else (0, set(), set()))


def test_a_negative_ring_is_refused_for_any_source(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="ring must be at least 0, got -1"):
        next(iter_frames(str(tmp_path), ring=-1))


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=400), prefix=st.sampled_from([b"", b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff"]))
def test_random_bytes_read_as_an_image_or_a_one_line_error(tmp_path: Path, data: bytes, prefix: bytes) -> None:
    path = tmp_path / "random.png"
    path.write_bytes(prefix + data)
    try:
        image = read_image(path)
    except ImageReadError as error:
        assert "random.png" in str(error) and "\n" not in str(error)
    else:
        assert image.dtype in (np.uint8, np.uint16) and image.ndim in (2, 3)


@pytest.mark.parametrize("suffix", [".yaml", ".xml", ".json"])
def test_an_opencv_calibration_is_read(tmp_path: Path, suffix: str) -> None:
    # As OpenCV's calibration sample writes it, through cv2.FileStorage.
    path = tmp_path / f"camera{suffix}"
    matrix = np.array([[8567.5, 0.0, 510.2], [0.0, 8570.1, 513.9], [0.0, 0.0, 1.0]])
    distortion = np.array([[-3.0, 0.5, 0.001, -0.002, 0.0]])
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    storage.write("image_width", 1024)
    storage.write("image_height", 768)
    storage.write("camera_matrix", matrix)
    storage.write("distortion_coefficients", distortion)
    storage.release()
    width, height, read_matrix, read_distortion = read_opencv_camera(path)
    assert (width, height) == (1024, 768)
    np.testing.assert_array_equal(read_matrix, matrix)
    np.testing.assert_array_equal(read_distortion, distortion.ravel())


def test_an_opencv_file_without_the_keys_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "other.yaml"
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    storage.write("camera_matrix", np.eye(3))
    storage.release()
    with pytest.raises(SpotnavError, match="no distortion_coefficients"):
        read_opencv_camera(path)
    with pytest.raises(SpotnavError, match="no such file"):
        read_opencv_camera(tmp_path / "missing.yaml")
    (tmp_path / "text.yaml").write_text("not: [a, calibration")
    with pytest.raises(SpotnavError, match=r"text\.yaml"):
        read_opencv_camera(tmp_path / "text.yaml")
