"""render_panels (softhand_sim.handmodel.render): posed skins side by side from one fixed camera with
the tracked joints drawn over them (what tools/fit_picture.py draws for the README)."""
import numpy as np
from matplotlib.image import imread

from softhand_sim import handmodel
from softhand_sim.handmodel.kinematics import forward_kinematics
from softhand_sim.handmodel.render import JOINT_RGB, MARK_RGB, render_panels, view_matrix
from softhand_sim.handmodel.rigid_skin import RigidSkin

SHIFT = 0.10  # [m] the second panel's hand lies this far along +x (screen right in the dorsal view)


def _color_columns(img, rgb, tol=0.12):
    """Column indices of the pixels within `tol` of colour rgb (alpha ignored)."""
    near = np.all(np.abs(img[:, :, :3] - np.asarray(rgb)) < tol, axis=2)
    return np.nonzero(near)[1]


def test_one_camera_for_both_panels_with_joints_and_marks(tmp_path):
    """The same open hand twice, the second shifted 10 cm along +x: the shared camera frame holds
    every skin vertex and joint of both, and in the picture the second panel's joints sit further
    right in their panel than the first's (a camera fitted to each panel would centre both);
    joint dots and fingertip crosses are drawn on both panels."""
    asset = handmodel.load_or_build_hand()
    joints, bones = forward_kinematics(np.r_[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], np.zeros((5, 4)))
    skin = RigidSkin(asset).pose(bones)[0]
    tips = joints[[5, 10, 15, 20, 25], :3]
    move = np.array([SHIFT, 0.0, 0.0])
    panels = [dict(skin_vertices=skin, skin_triangles=asset.skin_triangles, joints=joints[:, :3], marks=tips,
                   title="at the origin"),
              dict(skin_vertices=skin + move, skin_triangles=asset.skin_triangles, joints=joints[:, :3] + move,
                   marks=tips + move, title="10 cm along x")]
    path = tmp_path / "panels.png"
    limits = render_panels(panels, path, view="dorsal", panel_px=(300, 260), legend=("tracked", "simulated tips"))

    assert 10_000 < path.stat().st_size < 300_000
    screen = np.concatenate([skin, skin + move, joints[:, :3], joints[:, :3] + move]) @ view_matrix("dorsal")[:2].T
    assert np.all(screen[:, 0] > limits[0][0]) and np.all(screen[:, 0] < limits[0][1])
    assert np.all(screen[:, 1] > limits[1][0]) and np.all(screen[:, 1] < limits[1][1])

    img = imread(path)[: int(0.85 * 260)]  # above the legend, whose samples have the same colours
    half = img.shape[1] // 2
    for rgb in (JOINT_RGB, MARK_RGB):
        cols = _color_columns(img, rgb)
        left, right = cols[cols < half], cols[cols >= half] - half
        assert left.size > 50 and right.size > 50, (rgb, left.size, right.size)
    cols = _color_columns(img, JOINT_RGB)
    left, right = cols[cols < half], cols[cols >= half] - half
    width_px = half * SHIFT / (limits[0][1] - limits[0][0])  # the shift on screen, roughly (panel margins)
    assert right.mean() - left.mean() > 0.5 * width_px
