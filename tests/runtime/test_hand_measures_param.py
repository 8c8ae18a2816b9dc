"""The sim node's `hand_measures` parameter: 'default', a measures file, or 'auto' (the default
measures until softhand_sim.hand_sizer has fitted the user's: tests/runtime/test_hand_sizer.py)."""
import pytest

from softhand_sim.handmodel.measures import HandMeasures, scale_measures, write_measures_file
from softhand_sim.params import load_params
from softhand_sim.runtime import hand_measures, hand_measures_source


def test_default_and_file(tmp_path):
    assert load_params("sim_node")["hand_measures"] == "default"
    assert hand_measures("default") == HandMeasures()
    small = scale_measures(HandMeasures(), 0.85)
    path = tmp_path / "m.yaml"
    write_measures_file(path, small, "a test hand")
    assert hand_measures(str(path)) == small


def test_auto_starts_with_the_default_and_bad_file_refused(tmp_path):
    assert hand_measures("auto") == HandMeasures()
    assert [hand_measures_source(v) for v in ("default", "", "auto", "m.yaml")] == ["default", "default", "auto", "file"]
    bad = tmp_path / "bad.yaml"
    bad.write_text("hand_measures: {palm_length: 2.0}\n")
    with pytest.raises(ValueError, match="bad.yaml"):
        hand_measures(str(bad))
    with pytest.raises(ValueError, match="missing.yaml"):
        hand_measures(str(tmp_path / "missing.yaml"))
