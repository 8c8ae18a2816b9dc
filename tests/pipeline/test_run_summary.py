"""run_summary's latency figure: start-up is reported apart, not mixed into the percentiles."""
import numpy as np

from softhand_sim.commands.run_summary import frame_latency_ms


def test_latency_leaves_out_frames_before_the_first_bones():
    """Tracker frames every 10 ms from t = 0, /hand/bones every 1/60 s from t = 1.0 s: start-up is
    1.0 s; each later frame waits for the next bones message, so its latency lies in (0, 1/60 s]
    and the frames of the first second are not counted."""
    tracker = np.arange(0.0, 3.0, 0.01)
    bones = 1.0 + np.arange(0, 120) / 60.0
    latency, startup = frame_latency_ms(tracker, bones)
    assert np.isclose(startup, 1.0)
    assert len(latency) == np.sum((tracker >= 1.0) & (tracker < bones[-1]))
    assert latency.min() > 0.0 and latency.max() <= 1e3 / 60.0 + 1e-9
    assert frame_latency_ms([], bones)[0].size == 0
