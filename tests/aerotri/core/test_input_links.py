"""Input folders with broken links are refused by name (trial-paths): a project copied with a relative `lidar` link
ran on as "no LiDAR strips" (the true ortho became a conventional one on a 25 m tie-point DEM, exit 0), every frame
link broken read as "a LiDAR-only project"; trajectory files named *.TXT were passed over."""

from __future__ import annotations

import pytest

from aerotri.core.errors import InputError
from aerotri.core.project import Project, input_files


def test_a_broken_lidar_link_is_no_missing_lidar(tmp_path):
    p = Project(tmp_path, {})
    assert p.lidar_strips() == []  # no lidar folder: no LiDAR
    (tmp_path / "lidar").symlink_to("../lidar_src")
    with pytest.raises(InputError, match=r"lidar: a link to \.\./lidar_src, which does not exist"):
        p.lidar_strips()


def test_a_broken_strip_or_frame_link_is_named(tmp_path):
    (tmp_path / "lidar").mkdir()
    (tmp_path / "lidar" / "s1.las").write_bytes(b"")
    (tmp_path / "lidar" / "s2.LAZ").symlink_to(tmp_path / "gone" / "s2.laz")
    (tmp_path / "lidar" / "notes.txt").symlink_to(tmp_path / "gone" / "notes.txt")  # not a strip: not judged
    with pytest.raises(InputError, match=r"1 of its LiDAR strips are links to files that do not exist \(s2.LAZ ->"):
        Project(tmp_path, {}).lidar_strips()
    (tmp_path / "lidar" / "s2.LAZ").unlink()
    assert [f.name for f in Project(tmp_path, {}).lidar_strips()] == ["s1.las"]
    (tmp_path / "images").mkdir()
    (tmp_path / "images" / "f1.tif").symlink_to(tmp_path / "moved" / "f1.tif")
    with pytest.raises(InputError, match="frames are links to files that do not exist"):
        input_files(tmp_path / "images", (".tif",), "frames")


def test_trajectories_in_upper_case_are_read(tmp_path):
    (tmp_path / "trajectory").mkdir()
    for name in ("strip_01.TXT", "strip_02.txt", "readme.md"):
        (tmp_path / "trajectory" / name).write_text("x")
    assert [f.name for f in Project(tmp_path, {}).trajectories()] == ["strip_01.TXT", "strip_02.txt"]


def test_two_strips_of_one_name_are_refused_before_any_stage(tmp_path):
    (tmp_path / "lidar").mkdir()
    for name in ("strip_01.las", "strip_01.LAZ", "strip_02.laz"):
        (tmp_path / "lidar" / name).write_bytes(b"")
    with pytest.raises(InputError, match="two strips of one name, strip_01.LAZ and strip_01.las"):
        Project(tmp_path, {}).lidar_strips()
