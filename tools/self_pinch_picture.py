#!/usr/bin/env python3
"""Draw the pads of a tight tip pinch with and without skin-skin contact (sim parameter
self_contact), as sim_node runs it: the default hand driven through its bone targets into a
pinch whose tracked tips are 2 mm apart, closer than the two pads are thick
(scenarios.self_contact.runtime_tip_pinch, the pinch of tests/runtime/test_runtime_self_contact.py).

Three panels: the pinch with self contact (skin-skin contact points in red), and a section of
the thumb's and the index's distal skin through both pads, without self contact (the pads pass
into each other) and with it (they meet and flatten).

    python tools/self_pinch_picture.py [OUT.png]      # default docs/img/self_pinch.png
"""
import argparse
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402

from softhand_sim.handmodel.render import draw_joints, draw_scene, MARK_RGB  # noqa: E402
from softhand_sim.handmodel.rigid_skin import skin_segments  # noqa: E402
from softhand_sim.physics.rotations import quat_to_matrix  # noqa: E402
from softhand_sim.scenarios.self_contact import INDEX_DISTAL, THUMB_DISTAL, runtime_tip_pinch  # noqa: E402
from softhand_sim.topics import SKIN_OBJECT  # noqa: E402

THUMB_RGB, INDEX_RGB = (0.80, 0.35, 0.20), (0.20, 0.40, 0.80)


def distal_faces(triangles, segment, bone):
    """The skin triangles whose three vertices lie in `bone`'s segment."""
    return triangles[np.all(segment[triangles] == bone, axis=1)]


def section_plane(skin, triangles, segment, bone_poses):
    """(origin, normal, in-plane axes e1, e2) of a plane through both pads: it holds the line from
    the thumb pad's centre to the index pad's (e1) and the thumb's distal bone axis."""
    centre = {b: skin[np.unique(distal_faces(triangles, segment, b))].mean(axis=0) for b in (THUMB_DISTAL, INDEX_DISTAL)}
    e1 = centre[INDEX_DISTAL] - centre[THUMB_DISTAL]
    e1 /= np.linalg.norm(e1)
    axis = quat_to_matrix(bone_poses[THUMB_DISTAL, 3:])[:, 0]
    normal = np.cross(e1, axis)
    normal /= np.linalg.norm(normal)
    e2 = np.cross(normal, e1)
    return 0.5 * (centre[THUMB_DISTAL] + centre[INDEX_DISTAL]), normal, e1, e2


def draw_section(ax, skin, triangles, segment, plane, title):
    """The two distal skins cut by `plane`, as outlines in the plane's axes [mm]; returns the
    deepest overlap along e1 [mm] (how far the thumb's outline reaches past the index's)."""
    origin, normal, e1, e2 = plane
    reach = {}
    for bone, rgb, label in ((THUMB_DISTAL, THUMB_RGB, "thumb pad"), (INDEX_DISTAL, INDEX_RGB, "index pad")):
        mesh = trimesh.Trimesh(skin, distal_faces(triangles, segment, bone), process=False)
        lines = trimesh.intersections.mesh_plane(mesh, normal, origin)  # (n, 2, 3) segments
        uv = np.stack([(lines - origin) @ e1, (lines - origin) @ e2], axis=-1) * 1e3
        for k, seg in enumerate(uv):
            ax.plot(seg[:, 0], seg[:, 1], color=rgb, linewidth=1.6, label=label if k == 0 else None)
        near = np.abs(uv[..., 1]) < 2.0  # within 2 mm of the line between the pad centres
        reach[bone] = uv[..., 0][near].max() if bone == THUMB_DISTAL else uv[..., 0][near].min()
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("mm, thumb pad -> index pad", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7, loc="lower right", frameon=False)
    return reach[THUMB_DISTAL] - reach[INDEX_DISTAL]


def draw(runs, out, tip_gap, view=(60.0, 10.0)):
    """Write the picture of `runs` {self_contact: (runtime, last step output)} to `out`; returns
    its figures: pad contacts, force [N], the thumb pad's contact area [mm^2] and deepest point
    [mm] with self contact, and the section's overlap [mm] without and with it."""
    rt, last = runs[True]
    triangles = np.asarray(rt.asset.skin_triangles)
    segment = skin_segments(rt.asset)[0]
    skin = {on: runs[on][1].hands["right"].skin_vertices for on in runs}
    plane = section_plane(skin[True], triangles, segment, last.bone_poses)
    c = last.contacts
    pads = (c["objects"] == SKIN_OBJECT) & np.isin(c["bone"], [THUMB_DISTAL, INDEX_DISTAL])
    on_thumb = pads & (c["bone"] == THUMB_DISTAL)
    force = float(np.linalg.norm(c["forces"][on_thumb].sum(axis=0)))
    # the patch: the skin area of the thumb pad's points in contact (each point carries half its
    # vertex area, point_area, since every pair is tested both ways)
    area_mm2 = 1e6 * 2.0 * float(rt.self_contact.system.model.point_area[c["point"][on_thumb]].sum())
    depth_mm = 1e3 * float(np.nanmax(c["depth"][pads])) if pads.any() else float("nan")

    fig, axes = plt.subplots(1, 3, figsize=(13.2, 4.2), dpi=100, gridspec_kw={"width_ratios": [1.3, 1, 1]})
    draw_scene(axes[0], skin[True], triangles, (), tuple(view))
    draw_joints(axes[0], c["points"][pads], tuple(view), rgb=MARK_RGB, size=4.0, marker=".", zorder=5)
    axes[0].set_title(f"self contact on: {int(pads.sum())} pad contacts, net {force:.2f} N on the thumb pad\n"
                      f"over {area_mm2:.0f} mm\u00b2 of its skin, deepest point {depth_mm:.2f} mm under the other pad",
                      fontsize=9)
    off = draw_section(axes[1], skin[False], triangles, segment, plane,
                       "self contact off: the pads pass into each other")
    on = draw_section(axes[2], skin[True], triangles, segment, plane, "self contact on: the pads meet and flatten")
    lim = (min(axes[1].get_xlim()[0], axes[2].get_xlim()[0]), max(axes[1].get_xlim()[1], axes[2].get_xlim()[1]))
    for ax in axes[1:]:
        ax.set_xlim(*lim)
    fig.suptitle(f"tip pinch, tracked tips {1e3 * tip_gap:.0f} mm apart (sim_node's runtime, default hand); "
                 f"section through both pads: overlap {off:.1f} mm without, {on:.1f} mm with self contact",
                 fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    fig.savefig(out)
    plt.close(fig)
    return {"pad_contacts": int(pads.sum()), "force_n": force, "area_mm2": area_mm2, "deepest_mm": depth_mm,
            "overlap_off_mm": float(off), "overlap_on_mm": float(on)}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", nargs="?", default="docs/img/self_pinch.png", help="PNG to write")
    parser.add_argument("--tip-gap", type=float, default=0.002, help="tracked thumb-index tip gap [m] (default 0.002)")
    parser.add_argument("--view", type=float, nargs=2, default=(60.0, 10.0), metavar=("AZ", "EL"),
                        help="camera azimuth and elevation [deg] of the first panel")
    args = parser.parse_args(argv)
    if not 0.0 <= args.tip_gap <= 0.05:
        parser.error(f"--tip-gap must be within 0..0.05 m, got {args.tip_gap}")
    runs = {on: runtime_tip_pinch(on, tip_gap=args.tip_gap) for on in (False, True)}
    f = draw(runs, args.out, args.tip_gap, args.view)
    print(f"wrote {args.out}: pad contacts {f['pad_contacts']}, force {f['force_n']:.2f} N over "
          f"{f['area_mm2']:.1f} mm^2 of the thumb pad, deepest "
          f"{f['deepest_mm']:.2f} mm; section overlap {f['overlap_off_mm']:.2f} mm off, {f['overlap_on_mm']:.2f} mm on")
    return 0


if __name__ == "__main__":
    sys.exit(main())
