"""Settings made in code get the checks of project.toml and the command line (trial-api F4): AdjustSettings(alpha=5)
(5 meant as 5 %) switched the data snooping off without a word (0 observations removed against 3), a negative image
sigma ended in a gtsam traceback, a NaN one in "datum defect", a two-value lever arm in a numpy broadcast error,
self_calibration="pp" was read letter by letter, and a preset changed with dataclasses.replace was simulated with a
strip spacing of -207.36 m."""

from __future__ import annotations

import dataclasses
import math

import pytest

from aerotri.adjust.pipeline import AdjustSettings
from aerotri.core.errors import ConfigError, InputError
from aerotri.core.settings import settings_of
from aerotri.sim.config import load_preset
from aerotri.sim.project import simulate, simulate_observations


@pytest.mark.parametrize("change, message", [
    (dict(alpha=5.0), "AdjustSettings.alpha = 5.0: out of range"),
    (dict(image_sigma_px=-0.3), "AdjustSettings.image_sigma_px = -0.3: out of range"),
    (dict(image_sigma_px=math.nan), "AdjustSettings.image_sigma_px = nan: expected a number"),
    (dict(lever_arm_m=(0.05, -0.12)), r"AdjustSettings.lever_arm_m = \[0.05, -0.12\]: expected 3 values"),
    (dict(gnss_correction="drift"), "AdjustSettings.gnss_correction = 'drift': expected one of"),
])
def test_a_library_call_refuses_what_project_toml_refuses(change, message):
    with pytest.raises(ConfigError, match=message):
        settings_of(dataclasses.replace(AdjustSettings(), **change), AdjustSettings)


def test_a_library_call_gets_the_values_project_toml_would_give():
    st = settings_of(AdjustSettings(self_calibration="pp", check="chk01"), AdjustSettings).settings
    assert st.self_calibration == ("pp",) and st.check == ("chk01",)
    plain = AdjustSettings()
    assert settings_of(plain, AdjustSettings).settings is plain  # nothing to convert: the caller's own object


def test_a_preset_changed_in_code_is_checked_before_it_is_simulated(tmp_path):
    p = load_preset("tiny")
    bad = dataclasses.replace(p, flight=dataclasses.replace(p.flight, side_overlap=1.5))
    for run in (simulate, simulate_observations):
        with pytest.raises((ConfigError, InputError), match="side_overlap"):
            run(bad, tmp_path / run.__name__)
        assert not (tmp_path / run.__name__).exists()
