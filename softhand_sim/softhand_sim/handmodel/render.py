"""CPU rendering of the hand (and simple scene objects) to PNG with matplotlib.

Orthographic projection, painter's algorithm (triangles sorted back to front) and Lambert
shading with a head light plus a key light; no OpenGL needed, a 24k-triangle skin draws in about
a second. `draw_scene` is the general entry point (a posed skin plus spheres, boxes, cylinders,
capsules), `render_hand_png` draws an asset from the dorsal and palmar sides, `render_frames`
draws a sequence of posed skins side by side (a preview strip), `render_panels` draws posed skins
side by side from one fixed camera with tracked joints (`draw_joints`) over them.
"""
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402

from softhand_sim.handmodel.skeleton_names import JOINT_INDEX  # noqa: E402
from softhand_sim.physics.rotations import quat_to_matrix  # noqa: E402

SKIN_RGB = (0.93, 0.74, 0.62)
OBJECT_RGB = (0.45, 0.62, 0.85)
TET_RGB = (0.55, 0.75, 0.55)
JOINT_RGB = (0.05, 0.25, 0.75)
MARK_RGB = (0.85, 0.1, 0.1)


def _chain(*names):
    return tuple((JOINT_INDEX[a], JOINT_INDEX[b]) for a, b in zip(names, names[1:]))


# The lines between the 26 tracked (OpenXR) joints that draw a hand skeleton: each digit from the
# wrist through its joints to the tip, and the knuckle row.
TRACKED_HAND_LINES = _chain("WRIST", "THUMB_METACARPAL", "THUMB_PROXIMAL", "THUMB_DISTAL", "THUMB_TIP") + tuple(
    seg for f in ("INDEX", "MIDDLE", "RING", "LITTLE")
    for seg in _chain("WRIST", f"{f}_METACARPAL", f"{f}_PROXIMAL", f"{f}_INTERMEDIATE", f"{f}_DISTAL", f"{f}_TIP")
) + _chain("INDEX_PROXIMAL", "MIDDLE_PROXIMAL", "RING_PROXIMAL", "LITTLE_PROXIMAL")

# View rotations: rows are the screen right, screen up and toward-viewer axes in world coords.
VIEWS = {
    "dorsal": np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]),  # from +z (back of the hand)
    "palmar": np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]]),  # from -z
    "side": np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]),  # from -y, z up
    "front": np.array([[0, 1.0, 0], [0, 0, 1.0], [1.0, 0, 0]]),  # from +x
}


def view_matrix(view):
    """A named view, (azimuth_deg, elevation_deg) of a camera looking at the origin, or a 3x3."""
    if isinstance(view, str):
        if view not in VIEWS:
            raise ValueError(f"unknown view {view!r}; known: {sorted(VIEWS)} or (azimuth, elevation)")
        return VIEWS[view]
    v = np.asarray(view, dtype=np.float64)
    if v.shape == (3, 3):
        return v
    if v.shape != (2,):
        raise ValueError(f"view must be a name, (azimuth, elevation) or a 3x3 matrix, got {view!r}")
    az, el = np.radians(v)
    toward = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    right = np.cross([0.0, 0.0, 1.0], toward)
    right = right / np.linalg.norm(right) if np.linalg.norm(right) > 1e-9 else np.array([0.0, 1.0, 0.0])
    up = np.cross(toward, right)
    return np.vstack([right, up, toward])


def object_mesh(shape, dims, pose):
    """Triangle mesh (vertices, faces) of a scene object in the world; pose = [p, q xyzw]."""
    dims = dict(dims)
    if shape == "sphere":
        m = trimesh.creation.icosphere(subdivisions=3, radius=dims["radius"])
    elif shape == "box":
        if "size" in dims:
            ext = dims["size"]
        elif "half_extents" in dims:
            ext = 2.0 * np.asarray(dims["half_extents"])
        else:
            raise ValueError(f"box dims need 'size' or 'half_extents', got {sorted(dims)}")
        m = trimesh.creation.box(extents=ext)
    elif shape == "cylinder":
        m = trimesh.creation.cylinder(radius=dims["radius"], height=dims["length"], sections=32)
    elif shape == "capsule":
        m = trimesh.creation.capsule(radius=dims["radius"], height=dims["length"], count=[24, 12])
    else:
        raise ValueError(f"cannot draw object shape {shape!r} (sphere, box, cylinder, capsule)")
    pose = np.asarray(pose, dtype=np.float64)
    rot = quat_to_matrix(pose[3:7])
    return m.vertices @ rot.T + pose[:3], np.asarray(m.faces)


def _shade(tri_world, view_rot, rgb):
    n = np.cross(tri_world[:, 1] - tri_world[:, 0], tri_world[:, 2] - tri_world[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-18)
    toward = view_rot[2]
    key = 0.6 * toward + 0.5 * view_rot[1] - 0.3 * view_rot[0]
    key /= np.linalg.norm(key)
    lam = 0.25 + 0.45 * np.clip(n @ toward, 0, 1) + 0.35 * np.clip(n @ key, 0, 1)
    return np.clip(np.asarray(rgb)[None, :] * lam[:, None], 0, 1)


def draw_scene(ax, skin_vertices, skin_triangles, objects=(), view="dorsal", skin_rgb=SKIN_RGB,
               extra_meshes=(), margin=0.01, limits=None):
    """Draw a posed skin and scene objects onto a 2D matplotlib axes.

    objects: iterable of (shape, dims dict, pose (7,)); extra_meshes: (vertices, faces, rgb,
    alpha) drawn in the same depth order (e.g. tets or bone capsules). Back faces are culled
    for closed meshes, the rest is painted back to front. limits: a fixed camera frame
    ((x0, x1), (y0, y1)) in view coordinates [m] (see `view_limits`); by default the frame fits
    what is drawn, so a sequence drawn with `limits` keeps one camera while things move.
    """
    rot = view_matrix(view)
    meshes = [(np.asarray(skin_vertices, float), np.asarray(skin_triangles), skin_rgb, 1.0)]
    for shape, dims, pose in objects:
        v, f = object_mesh(shape, dims, pose)
        meshes.append((v, f, OBJECT_RGB, 1.0))
    meshes += list(extra_meshes)
    polys, colors, depth = [], [], []
    for v, f, rgb, alpha in meshes:
        tri = v[f]
        cam = tri @ rot.T
        nz = np.cross(cam[:, 1] - cam[:, 0], cam[:, 2] - cam[:, 0])[:, 2]
        keep = nz > 0.0 if alpha >= 1.0 else np.ones(len(f), bool)
        col = np.concatenate([_shade(tri[keep], rot, rgb), np.full((keep.sum(), 1), alpha)], axis=1)
        polys.append(cam[keep][:, :, :2])
        colors.append(col)
        depth.append(cam[keep][:, :, 2].mean(axis=1))
    polys, colors, depth = np.concatenate(polys), np.concatenate(colors), np.concatenate(depth)
    order = np.argsort(depth, kind="stable")
    # autolim=False: the limits are set below; the data limits of ~20,000 polygons took a third of
    # the drawing time of a preview
    ax.add_collection(PolyCollection(polys[order], facecolors=colors[order], edgecolors="none",
                                     antialiased=False), autolim=False)
    if limits is None:
        lo, hi = polys.reshape(-1, 2).min(0) - margin, polys.reshape(-1, 2).max(0) + margin
        limits = ((lo[0], hi[0]), (lo[1], hi[1]))
    ax.set_xlim(*limits[0])
    ax.set_ylim(*limits[1])
    ax.set_aspect("equal")
    ax.axis("off")
    return ax


def view_limits(points, view, margin=0.01):
    """The camera frame ((x0, x1), (y0, y1)) [m] of `view` that shows every world point (n, 3)."""
    cam = np.asarray(points, dtype=np.float64).reshape(-1, 3) @ view_matrix(view)[:2].T
    lo, hi = cam.min(axis=0) - margin, cam.max(axis=0) + margin
    return (float(lo[0]), float(hi[0])), (float(lo[1]), float(hi[1]))


def scene_to_rgb(skin_vertices, skin_triangles, objects=(), view="dorsal", size_px=(480, 360), dpi=100):
    """Render one scene to an RGB uint8 array (H, W, 3)."""
    fig = plt.figure(figsize=(size_px[0] / dpi, size_px[1] / dpi), dpi=dpi)
    ax = fig.add_axes([0, 0, 1, 1])
    draw_scene(ax, skin_vertices, skin_triangles, objects, view)
    fig.canvas.draw()
    rgb = np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()
    plt.close(fig)
    return rgb


def render_frames(skin_vertices_sequence, skin_triangles, path, objects_sequence=None, view="side",
                  titles=None, panel_px=(360, 300), dpi=100, same_scale=False):
    """Write a PNG strip with one panel per posed skin (and its objects) of a sequence.
    same_scale: one set of axis limits for every panel (motion between panels shows)."""
    n = len(skin_vertices_sequence)
    fig, axes = plt.subplots(1, n, figsize=(panel_px[0] * n / dpi, panel_px[1] / dpi), dpi=dpi,
                             squeeze=False)
    for i, v in enumerate(skin_vertices_sequence):
        objs = objects_sequence[i] if objects_sequence is not None else ()
        draw_scene(axes[0, i], v, skin_triangles, objs, view)
        if titles is not None:
            axes[0, i].set_title(titles[i], fontsize=9)
    if same_scale:
        lo = np.min([[ax.get_xlim()[0], ax.get_ylim()[0]] for ax in axes[0]], axis=0)
        hi = np.max([[ax.get_xlim()[1], ax.get_ylim()[1]] for ax in axes[0]], axis=0)
        for ax in axes[0]:
            ax.set_xlim(lo[0], hi[0])
            ax.set_ylim(lo[1], hi[1])
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def capsule_meshes(asset, rgb=(0.95, 0.95, 0.9)):
    """World-space triangle meshes of the bone capsules at rest (for overlays)."""
    out = []
    for i in range(asset.bone_rest_pose.shape[0]):
        a, b, r = asset.bone_capsule_a[i], asset.bone_capsule_b[i], asset.bone_capsule_radius[i]
        h = float(np.linalg.norm(b - a))
        m = trimesh.creation.capsule(radius=r, height=max(h, 1e-6), count=[12, 8])
        # trimesh capsules lie along z: turn z onto the bone's x axis, then into the world
        local = m.vertices[:, [2, 0, 1]] + 0.5 * (a + b)
        pose = asset.bone_rest_pose[i]
        out.append((local @ quat_to_matrix(pose[3:]).T + pose[:3], np.asarray(m.faces)[:, [0, 1, 2]], rgb, 1.0))
    return out


def render_hand_png(asset, path, views=("dorsal", "palmar"), show_tets=False, show_bones=False,
                    panel_px=(520, 420), dpi=100):
    """Write a PNG of the hand asset seen from each of `views`; optionally overlay the tissue
    surface (translucent) and the bone capsules (depth-sorted with the opaque skin, so only the
    parts that poke through show)."""
    n = len(views)
    fig, axes = plt.subplots(1, n, figsize=(panel_px[0] * n / dpi, panel_px[1] / dpi), dpi=dpi,
                             squeeze=False)
    for i, view in enumerate(views):
        extra = []
        if show_tets:
            extra.append((asset.tet_nodes, asset.tet_surface_triangles, TET_RGB, 0.35))
        if show_bones:
            extra += capsule_meshes(asset)
        draw_scene(axes[0, i], asset.skin_vertices, asset.skin_triangles, (), view,
                   extra_meshes=extra)
        axes[0, i].set_title(f"{asset.side} hand, {view}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def draw_joints(ax, points, view, lines=(), rgb=JOINT_RGB, size=14.0, marker="o", zorder=3):
    """Points (n, 3) [m] (e.g. tracked joints) as markers, and lines (pairs of point indices),
    projected like draw_scene's `view` and drawn over everything (joints inside the skin show)."""
    cam = np.asarray(points, dtype=np.float64).reshape(-1, 3) @ view_matrix(view)[:2].T
    for a, b in lines:
        ax.plot(cam[[a, b], 0], cam[[a, b], 1], color=rgb, linewidth=1.0, alpha=0.8, zorder=zorder)
    ax.scatter(cam[:, 0], cam[:, 1], s=size, color=rgb, marker=marker, zorder=zorder + 1, linewidths=1.2)
    return ax


def render_panels(panels, path, view="dorsal", panel_px=(420, 400), dpi=100, margin=0.01, legend=None):
    """Write a PNG of posed skins side by side, all seen from one fixed camera (`view`, one frame
    that shows every panel's skin and points, so sizes compare across panels).

    panels: dicts with skin_vertices (V, 3) [m], skin_triangles (T, 3), title, and optionally joints
    (n, 3+) [m] (positions first) drawn as dots with TRACKED_HAND_LINES when n == 26, and marks (m, 3) drawn as crosses.
    legend: labels (joints, marks) of a figure legend. Returns the camera frame ((x0, x1), (y0, y1)).
    """
    everything = [p["skin_vertices"] for p in panels] + [p[k] for p in panels for k in ("joints", "marks") if k in p]
    limits = view_limits(np.concatenate([np.asarray(a, dtype=np.float64)[..., :3].reshape(-1, 3) for a in everything]),
                         view, margin)
    fig, axes = plt.subplots(1, len(panels), figsize=(panel_px[0] * len(panels) / dpi, panel_px[1] / dpi), dpi=dpi,
                             squeeze=False)
    for ax, p in zip(axes[0], panels):
        draw_scene(ax, p["skin_vertices"], p["skin_triangles"], (), view, limits=limits)
        if "joints" in p:
            joints = np.asarray(p["joints"], dtype=np.float64)[:, :3]
            draw_joints(ax, joints, view, TRACKED_HAND_LINES if len(joints) == len(JOINT_INDEX) else ())
        if "marks" in p:
            draw_joints(ax, np.asarray(p["marks"], dtype=np.float64)[:, :3], view, rgb=MARK_RGB, size=30.0,
                        marker="x", zorder=5)
        ax.set_title(p.get("title", ""), fontsize=9)
    if legend:
        from matplotlib.lines import Line2D

        handles = [Line2D([], [], color=JOINT_RGB, marker="o", linewidth=1.0, label=legend[0]),
                   Line2D([], [], color=MARK_RGB, marker="x", linestyle="none", label=legend[1])][:len(legend)]
        fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.05 if legend else 0, 1, 0.98))
    fig.savefig(path)
    plt.close(fig)
    return limits
