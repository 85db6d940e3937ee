"""The simulator presets: every shipped preset loads, and its [chain] stage options are ones the chain
accepts (aerotri run checks them again when it reads the simulated project.toml)."""

from __future__ import annotations

import pytest

from aerotri.chain.options import read_stage_sections
from aerotri.sim.config import available_presets, load_preset


@pytest.mark.parametrize("name", available_presets())
def test_preset_stage_options_are_accepted_by_the_chain(name):
    cfg = load_preset(name)
    assert set(available_presets()) >= {"tiny", "demo", "dmc"}
    options = read_stage_sections(cfg.chain, f"{name} [chain]")
    for section, table in cfg.chain.items():
        for key, value in table.items():
            if not isinstance(value, dict):
                got = getattr(getattr(options, section), key)
                assert got == (tuple(value) if isinstance(value, list) else value), (section, key)


def test_preset_is_typed_and_checked(tmp_path):
    """A preset is one frozen dataclass per table: keys it leaves out take their defaults, a misspelt key or a
    value of the wrong type stops with the file, the table and the key (they were taken silently before)."""
    import dataclasses

    from aerotri.core.errors import InputError
    from aerotri.sim.config import PRESET_DIR

    p = load_preset("tiny")
    assert p.render.tile_px == 0 and p.render.compress == "none" and p.observations.tie_points_per_frame == 130
    assert p.scene.counts_for_m is None and p.lidar.boresight_error_deg == (0.0, 0.0, 0.0)
    assert isinstance(p.scene.road_width_m, tuple) and isinstance(p.flight.speed_mps, float)
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.flight.strips = 3
    assert load_preset("tiny", ["render.tile_px=64", "flight.speed_mps=60"]).flight.speed_mps == 60.0
    bad = tmp_path / "bad.toml"
    bad.write_text((PRESET_DIR / "tiny.toml").read_text().replace("[scene]\n", "[scene]\nbuildngs = 3\n", 1))
    with pytest.raises(InputError, match=r"bad.toml \[scene\]: unknown key 'buildngs'"):
        load_preset(str(bad))
    with pytest.raises(InputError, match=r"\[scene\] ponds = 2.5: expected a whole number"):
        load_preset("tiny", ["scene.ponds=2.5"])
    with pytest.raises(InputError, match="unknown parameter 'scene.buildngs'"):
        load_preset("tiny", ["scene.buildngs=3"])
    with pytest.raises(InputError, match=r"building_height_m must be \[min, max\].*got \[5.0\]"):  # was a traceback
        load_preset("tiny", ["scene.building_height_m=[5.0]"])
