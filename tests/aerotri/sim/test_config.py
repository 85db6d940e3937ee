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
    with pytest.raises(InputError, match=r"\[scene\] building_height_m = \[5.0\]: expected 2 values"):  # was a traceback
        load_preset("tiny", ["scene.building_height_m=[5.0]"])


@pytest.mark.parametrize("override, message", [
    ("flight.strips=0", r"tiny.toml \[flight\] strips = 0: out of range, expected >= 1 and <= 200"),
    ("camera.focal_mm=1.0", r"\[camera\] focal_mm = 1.0: out of range, expected > 1 and <= 1000"),
    ("lidar.boresight_error_deg=[0.0, 0.0, 7.0]", r"\[lidar\] boresight_error_deg = 7.0: out of range, expected >= -5"),
    ("lidar.format=\"xyz\"", r"\[lidar\] format = 'xyz': expected one of las, laz"),
    ("render.bits=16", r"\[render\] bits = 16: expected one of 8, 12"),
    ("render.tile_px=100", r"\[render\]: tile_px must be a multiple of 32"),
    ("camera.sensor_height_mm=40.0", r"\[camera\]: sensor_height_mm = 40 over height = .* expected square pixels"),
    ("scene.building_height_m=[50.0, 5.0]", r"\[scene\] building_height_m = \[50.0, 5.0\]: expected \[min, max\]"),
    ("lidar.height_above_ground_m=150.0", r"\[lidar\] height_above_ground_m = 150.0: does not clear the terrain"),
])
def test_preset_values_are_checked_by_their_settings(override, message):
    """Each table's ranges and choices are its fields' own (``setting(min=..., max=..., choices=...)``, read by
    ``from_table``, as project.toml's are); what no field can check alone is checked across the tables."""
    from aerotri.core.errors import InputError

    with pytest.raises(InputError, match=message):
        load_preset("tiny", [override])


def test_preset_missing_table_or_key_is_named(tmp_path):
    from aerotri.core.errors import InputError
    from aerotri.sim.config import PRESET_DIR

    text = (PRESET_DIR / "tiny.toml").read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text("\n".join(line for line in text.splitlines() if not line.startswith("pulse_rate_hz")))
    with pytest.raises(InputError, match=r"bad.toml \[lidar\]: missing key 'pulse_rate_hz'"):
        load_preset(str(bad))
    bad.write_text(text.replace("[truth]", "[truth_]"))
    with pytest.raises(InputError, match=r"unknown table \[truth_\]"):
        load_preset(str(bad))


def test_presets_page_is_current():
    """docs/presets.md is generated from the preset's dataclasses (ranges, defaults, units, meaning)."""
    from pathlib import Path

    from aerotri.sim.config import preset_reference

    page = Path(__file__).resolve().parents[3] / "docs" / "presets.md"
    assert page.read_text() == preset_reference() + "\n", "regenerate: python -c 'from aerotri.sim.config import " \
        "preset_reference; print(preset_reference())' > docs/presets.md"


@pytest.mark.parametrize("overrides, start", [
    (["flight.strips=0"], "--set flight.strips=0: "),
    (["flight.strips=5", "flight.strips=0"], "--set flight.strips=0: "),  # the last of a key is the one used
    (["scene.building_height_m=[50.0, 5.0]"], "--set scene.building_height_m=[50.0, 5.0]: "),
    (["lidar.height_above_ground_m=150.0"], "--set lidar.height_above_ground_m=150.0: "),
    (["flight.speed_mps=60", "lidar.height_above_ground_m=150.0"], "--set lidar.height_above_ground_m=150.0: "),
])
def test_a_refused_set_is_named_as_typed(overrides, start):
    """The option as the user typed it leads the message, for a field's own check and for the checks across
    tables alike; a refusal of the preset file's own value names no option."""
    from aerotri.core.errors import InputError

    with pytest.raises(InputError) as exc:
        load_preset("tiny", overrides)
    assert str(exc.value).startswith(start) and "tiny.toml [" in str(exc.value)


def test_a_refused_preset_value_names_no_option(tmp_path):
    from aerotri.core.errors import InputError
    from aerotri.sim.config import PRESET_DIR

    bad = tmp_path / "bad.toml"
    text = (PRESET_DIR / "tiny.toml").read_text()
    assert "\nstrips = 2\nframes_per_strip" in text
    bad.write_text(text.replace("\nstrips = 2\nframes_per_strip", "\nstrips = 0\nframes_per_strip", 1))
    with pytest.raises(InputError) as exc:
        load_preset(str(bad), ["flight.speed_mps=60"])
    assert str(exc.value).startswith(f"{bad} [flight] strips = 0: out of range")
