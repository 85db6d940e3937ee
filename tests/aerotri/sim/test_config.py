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
    options = read_stage_sections(cfg.get("chain", {}), f"{name} [chain]")
    for section, table in cfg.get("chain", {}).items():
        for key, value in table.items():
            if not isinstance(value, dict):
                got = getattr(getattr(options, section), key)
                assert got == (tuple(value) if isinstance(value, list) else value), (section, key)
