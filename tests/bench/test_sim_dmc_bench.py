"""bench/sim_dmc.py without making the block: unit costs and the projection of the full block from a smaller
one, the size estimate and the refusal to fill the disk."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_sim_dmc", ROOT / "bench" / "sim_dmc.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


PHASES = dict(scene=dict(wall_s=10.0, cpu_s=5.0), frames=dict(wall_s=100.0, cpu_s=80.0, frames=10, megapixels=1061.7),
              lidar=dict(wall_s=60.0, cpu_s=50.0, points=20_000_000), other=dict(wall_s=2.0, cpu_s=1.0),
              truth_rasters=dict(wall_s=50.0, cpu_s=40.0, megapixels=500.0))


def test_unit_costs_and_projection(bench):
    u = bench.unit_costs(PHASES)
    assert u["frame_s"] == 10.0 and u["frame_mp_per_s"] == pytest.approx(10.62, abs=0.01)
    assert u["frame_mp_per_cpu_s"] == pytest.approx(13.27, abs=0.01) and u["lidar_s_per_m_points"] == 3.0
    measured = dict(phases=PHASES, unit_costs=u, block=dict(scene_km2=5.0))
    full = dict(frames=120, lidar_pulses=300e6, lidar_points_planned=200e6, scene_km2=40.0, truth_megapixels=4000.0)
    p = bench.projection(measured, full)
    # 120 frames x 10 s, 200 M points x 3 s, 4000 MP at 10 MP/s, scene and other x 8 (the area)
    assert p["wall_s"] == dict(scene=80.0, frames=1200.0, lidar=600.0, truth_rasters=400.0, other=16.0, total=2296.0)
    assert p["cpu_s"]["total"] == pytest.approx(40 + 960 + 500 + 320 + 8)


def test_size_estimate_and_disk_guard(bench, tmp_path, monkeypatch):
    sub = ["flight.strips=2", "flight.frames_per_strip=5"]
    full, small = bench.estimated_gb([]), bench.estimated_gb(sub)
    assert 15 < full < 30 and 1 < small < 4  # 120 and 10 frames of 125 MB, LAZ, truth rasters at the GSD
    monkeypatch.setattr(bench.shutil, "disk_usage", lambda p: type("U", (), dict(free=5e9))())
    with pytest.raises(SystemExit, match="needs about 22 GB .* 5 GB free"):
        bench.make_block(tmp_path / "dmc_block", [])
    assert not (tmp_path / "dmc_block").exists()
