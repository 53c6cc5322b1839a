"""benchmarks/suites/spot_advice.py: the two-pass capture suite's settings (no simulation here)."""

from __future__ import annotations

import pytest

from benchmarks.harness.suite import SettingsError, all_suites


def test_first_pass_sizes_and_controls_are_checked():
    suite = all_suites()["spot_advice"]
    s = suite.settings(False, ["keeps=8,12", "controls=alone", "scenes=organic-occluded,outside-fov"])
    assert s.keeps == (8, 12) and s.controls == ("alone",) and s.scenes == ("organic-occluded", "outside-fov")
    with pytest.raises(SettingsError, match="keeps.*total=16.*16"):
        suite.settings(False, ["keeps=8,16"])
    with pytest.raises(SettingsError, match="controls.*spreadout"):
        suite.settings(False, ["controls=alone,spreadout"])


def test_beyond_view_per_scene_else_the_advisor_default():
    from benchmarks.suites.spot_advice import _beyond

    s = all_suites()["spot_advice"].settings(False, ["beyond_view_deg=outside-fov:30"])
    assert _beyond(s, "outside-fov") == "30" and _beyond(s, "dark-room") == "0"
