"""Viewing a run (README "Viewing a run"): the demo's recording holds what the Foxglove layout shows.

One `softhand demo` run of the short grasp bag (shared with test_demo_nodes), then: the contact force arrows and the total-force
label are recorded, the scene markers draw the table and the ground, every plot path of
docs/foxglove/softhand_layout.json yields numbers from the recording (the contact force rises above
zero while the hand holds the ball), and the preview pictures are written.
"""
import json
import re

import numpy as np
import pytest
from visualization_msgs.msg import Marker

from softhand_sim.ros import markers as mk
from softhand_sim.ros import msgs as rm

pytestmark = [pytest.mark.ros, pytest.mark.slow, pytest.mark.flaky(reruns=1, reruns_delay=2)]

_STEP = re.compile(r'\.(\w+)|\[:\]|\{(\w+)=="([^"]*)"\}')


def evaluate_path(path, msg):
    """Values of a Foxglove message path of the form /topic.field[:]{key=="v"}.field... on `msg`
    (the subset the layout uses: fields, whole-array slices, equality filters)."""
    rest = path[path.index("."):]
    values = [msg]
    pos = 0
    while pos < len(rest):
        m = _STEP.match(rest, pos)
        assert m, f"unsupported path syntax at {rest[pos:]!r}"
        if m.group(1):
            values = [getattr(v, m.group(1)) for v in values]
        elif m.group(0) == "[:]":
            values = [item for v in values for item in v]
        else:
            values = [v for v in values if str(getattr(v, m.group(2))) == m.group(3)]
        pos = m.end()
    return values


def read_topic(bag_dir, topic):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag_dir) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        return [store.deserialize_cdr(raw, c.msgtype) for c, _, raw in reader.messages(connections=conns)]


def test_demo_recording_shows_in_the_foxglove_layout(demo_run, repo_root):
    check_run_for_viewing(demo_run[0], repo_root)


def check_run_for_viewing(out, repo_root):
    """What the layout shows is in the run's recording, and the preview pictures exist."""
    bag = out / "bag"
    contact_msgs = read_topic(bag, mk.CONTACT_MARKERS_TOPIC)
    assert len(contact_msgs) > 20
    for msg in contact_msgs:
        assert [(m.ns, m.id, m.type) for m in msg.markers] == [
            (mk.ARROW_NS, 0, Marker.TRIANGLE_LIST), (mk.ARROW_NS, 1, Marker.TRIANGLE_LIST),
            (mk.TOTAL_NS, 0, Marker.TEXT_VIEW_FACING)]
        assert all(len(m.points) % (3 * mk.TRIANGLES_PER_ARROW) == 0 for m in msg.markers[:2])
    assert max(len(m.points) for msg in contact_msgs for m in msg.markers[:2]) > 0  # arrows were drawn

    scene = read_topic(bag, "/world/markers")[-1].markers
    assert {m.text for m in scene} >= {"table", "ground"}
    ground = next(m for m in scene if m.ns == rm.GROUND_NS)
    assert ground.pose.position.z + 0.5 * ground.scale.z == pytest.approx(0.0)

    layout = json.loads((repo_root / "docs" / "foxglove" / "softhand_layout.json").read_text())
    series = {}
    for key, cfg in layout["configById"].items():
        for p in cfg.get("paths", []) if key.startswith("Plot!") else []:
            if p["label"].startswith("left "):
                continue  # a right-hand run: the left hand's lines stay empty
            topic = p["value"].split(".")[0]
            values = [float(v) for msg in read_topic(bag, topic) for v in evaluate_path(p["value"], msg)]
            assert len(values) >= 3, f"{p['value']}: {len(values)} values in the recording"
            series[p["label"]] = values
    force = series["total contact force [N]"]
    assert max(force) > 0.1 and min(force) == 0.0, (min(force), max(force))  # touching, and not
    step = [v for v in series["sim step p50 [ms]"] if v == v]  # 'nan' until the first step
    assert len(step) >= 3 and all(0.0 < v < 1000.0 for v in step)
    # the live lag (record_node): NaN while the hand is still, else within the searched range and
    # the intermediate layer ahead of the simulated hand on average
    sim_lag = [v for v in series["right sim lag [ms]"] if v == v]
    inter_lag = [v for v in series["right intermediate lag [ms]"] if v == v]
    assert len(sim_lag) >= 2 and all(-40.0 <= v <= 160.0 for v in sim_lag + inter_lag), (sim_lag, inter_lag)
    assert np.median(inter_lag) < np.median(sim_lag), (inter_lag, sim_lag)

    assert (out / "preview.png").stat().st_size > 10_000 and (out / "preview.gif").stat().st_size > 10_000


def test_preview_camera_frames_the_run_with_the_table_and_the_ground():
    """camera_frame (one frame for every panel) holds every point of the run and, below it in the
    picture, the table's front edge and the ground in front of the table (outside its footprint)."""
    from softhand_sim.commands.preview import CAMERA_VIEW, _inside_static_footprint, camera_frame
    from softhand_sim.handmodel.render import view_matrix
    from softhand_sim.scene import load_scene

    scene = load_scene()
    table = scene.object("table")
    top = table.pose[2] + table.dims["size"][2] / 2
    run = np.array([[-0.05, -0.05, top + 0.01], [0.1, 0.08, top + 0.2]])  # a hand moving over the table
    (x0, x1), (y0, y1) = camera_frame(scene, run)
    rot = view_matrix(CAMERA_VIEW)

    def inside(p):
        u, v = rot[:2] @ p
        return x0 <= u <= x1 and y0 <= v <= y1

    assert all(inside(p) for p in run)
    # below the run, seen from the camera: the table's front edge, then the ground in front of it
    toward = rot[2, :2] / np.linalg.norm(rot[2, :2])
    centre = run.mean(axis=0)
    front = table.pose[1] - table.dims["size"][1] / 2  # the camera looks from -y
    s_edge = (front - centre[1]) / toward[1]
    edge = np.array([*(centre[:2] + s_edge * toward), top])
    assert abs(edge[0]) < table.dims["size"][0] / 2 and inside(edge)
    ground = np.array([[*(centre[:2] + (s_edge + d) * toward), scene.ground_height] for d in (0.01, 0.03)])
    assert all(inside(p) for p in ground)
    assert not _inside_static_footprint(scene, ground[:, :2]).any()
