"""``aerotri sim --help`` names every shipped preset (trial s98 L3: ``tall`` was accepted but listed nowhere)."""

import re
from pathlib import Path

from click.testing import CliRunner

from aerotri.cli import main


def test_the_help_names_every_shipped_preset():
    presets = sorted(p.stem for p in (Path(__file__).resolve().parents[3] / "datasets" / "presets").glob("*.toml"))
    r = CliRunner().invoke(main, ["sim", "--help"], terminal_width=200)
    assert r.exit_code == 0, r.output
    help_text = " ".join(r.output.split())
    listed = set(re.search(r"Preset name \(([^)]*)\)", help_text).group(1).replace(" ", "").split(","))
    assert presets and set(presets) <= listed, (presets, listed)
