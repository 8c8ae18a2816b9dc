"""Preview of a recorded run: key frames drawn from the recording with the CPU renderer.

Reads /hand/{side}/skin_marker of every hand (the skin as a triangle list; both hands drawn in one
picture) and /world/object_states (engine-side objects) from the rosbag2 directory, the static objects from the scene file, and draws them with
handmodel.render (matplotlib, painter's algorithm; no ROS, no GPU). Writes preview.png (a strip
of key frames) and preview.gif (the run, downsampled), both from one fixed camera with the table
and the ground in view.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from softhand_sim.scene import load_scene
from softhand_sim.topics import SIDES, hand_topic, side_of

# One fixed camera for every panel of preview.png and every frame of preview.gif: an elevated
# three-quarter view from the front (-y) of the table, framed once for the whole run, so the hand
# and the objects move in the picture and the table and the ground stay put.
CAMERA_VIEW = (-60.0, 40.0)  # (azimuth, elevation) [deg]
TABLE_RGB = (0.78, 0.74, 0.68)
GROUND_RGB = (0.62, 0.66, 0.6)
BACKDROP_CELL = 0.03  # [m] static objects are drawn as small triangles so depth sorting stays right
GROUND_CELL = 0.05    # [m] grid of the ground patch
GROUND_HALF = 1.0     # [m] the ground is drawn as a square of this half edge around the hand
GROUND_REACH = 0.06   # [m] of ground shown beyond the front edge of the table
FRAME_MARGIN = 0.02   # [m] around the hand, the objects and the ground patch in view
PANEL_WIDTH_IN = 2.8  # [in] width of one panel of preview.png; the height follows the frame
GIF_WIDTH_IN = 3.6    # [in] width of preview.gif (80 dpi)


def read_frames(bag_dir, max_frames=60):
    """[(t, triangle corners (3F, 3)), ...] and {name: [(t, pose (7,))]} from the recording.

    With two hands a frame holds both skins: it is taken at each skin marker of the last hand in
    SIDES order (the sim publishes both hands' markers in one tick), with the other hand's latest."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    from softhand_sim.ros.msgs import marker_points_from_cdr

    store = get_typestore(Stores.ROS2_JAZZY)
    skins, objects, latest = [], {}, {}
    marker_topics = {hand_topic(side, "skin_marker") for side in SIDES}
    with Reader(Path(bag_dir)) as reader:
        conns = [c for c in reader.connections if c.topic in marker_topics or c.topic == "/world/object_states"]
        # the hands that have markers (the recorder lists every hand's topic, messages or not)
        sides = [s for s in SIDES if any(c.topic == hand_topic(s, "skin_marker") and c.msgcount for c in conns)]
        for conn, t_ns, raw in reader.messages(connections=conns) if conns else ():
            t = t_ns * 1e-9
            if conn.topic in marker_topics:
                try:  # 70,000 points a skin: read where they lie, not as 70,000 objects
                    pts = marker_points_from_cdr(raw)
                except ValueError:
                    continue  # not a Marker's CDR: nothing to draw from it
                if pts.size and pts.shape[0] % 3 == 0:
                    latest[side_of(conn.topic)] = pts
                    if side_of(conn.topic) == sides[-1]:
                        skins.append((t, np.vstack(list(latest.values()))))
            elif (msg := store.deserialize_cdr(raw, conn.msgtype)).points:
                for name, tf in zip(msg.joint_names, msg.points[0].transforms):
                    pose = np.array([tf.translation.x, tf.translation.y, tf.translation.z,
                                     tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w])
                    objects.setdefault(name, []).append((t, pose))
    if len(skins) > max_frames:
        keep = np.linspace(0, len(skins) - 1, max_frames).round().astype(int)
        skins = [skins[i] for i in keep]
    return skins, objects


def _pose_at(track, t):
    times = np.array([s for s, _ in track])
    return track[int(np.clip(np.searchsorted(times, t), 0, len(track) - 1))][1]


def backdrop_meshes(scene, center):
    """The static objects and a ground patch around `center` as finely cut triangle meshes.

    [(vertices, faces, rgb, alpha)] for draw_scene's extra_meshes. Painter's algorithm sorts whole
    triangles, so the big faces of a table or the ground are cut into BACKDROP_CELL pieces.
    """
    import trimesh

    from softhand_sim.handmodel.render import object_mesh

    out = []
    for obj in scene.static_objects:
        if obj.shape == "mesh":
            continue  # a static mesh is not drawn (object_mesh knows primitives only)
        v, f = object_mesh(obj.shape, obj.dims, obj.pose)
        v, f = trimesh.remesh.subdivide_to_size(v, f, max_edge=BACKDROP_CELL)
        out.append((v, f, TABLE_RGB, 1.0))
    # the ground grid: lines every GROUND_CELL and on the static boxes' edges, cells under them left
    # out, so no ground triangle straddles a table edge (it would be sorted wrongly against the table)
    edges = [[], []]
    for obj in scene.static_objects:
        if obj.shape == "box":
            for axis in (0, 1):
                edges[axis] += [obj.pose[axis] - obj.dims["size"][axis] / 2, obj.pose[axis] + obj.dims["size"][axis] / 2]
    xs, ys = (np.unique(np.concatenate([np.arange(center[a] - GROUND_HALF, center[a] + GROUND_HALF + 1e-9, GROUND_CELL),
                                        np.clip(edges[a], center[a] - GROUND_HALF, center[a] + GROUND_HALF)]))
              for a in (0, 1))
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    verts = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, scene.ground_height)])
    idx = np.arange(gx.size).reshape(gx.shape)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    mid = 0.25 * (verts[a] + verts[b] + verts[c] + verts[d])[:, :2]
    free = ~_inside_static_footprint(scene, mid)
    a, b, c, d = a[free], b[free], c[free], d[free]
    out.append((verts, np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])]), GROUND_RGB, 1.0))
    return out


def _inside_static_footprint(scene, xy):
    """True where points xy (n, 2) lie over a static box (axis-aligned footprint)."""
    inside = np.zeros(len(xy), bool)
    for obj in scene.static_objects:
        if obj.shape == "box":
            half = 0.5 * np.asarray(obj.dims["size"][:2])
            inside |= np.all(np.abs(xy - obj.pose[:2]) <= half, axis=1)
    return inside


def camera_frame(scene, focus_points, view=CAMERA_VIEW):
    """The one camera frame ((x0, x1), (y0, y1)) of the whole preview.

    It shows every focus point (the hand and the objects over the whole run) and, below them, the
    ground just in front of the static objects (the table): the focus box's corners are carried
    toward the camera until they leave every static footprint, then GROUND_REACH further.
    """
    from softhand_sim.handmodel.render import view_limits, view_matrix

    pts = np.asarray(focus_points, dtype=np.float64).reshape(-1, 3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    corners = np.array([[x, y] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])])
    toward = view_matrix(view)[2, :2]
    toward = toward / max(np.linalg.norm(toward), 1e-9)
    ground = corners.copy()
    for _ in range(200):  # 2 m in 1 cm steps at most
        inside = _inside_static_footprint(scene, ground)
        if not inside.any():
            break
        ground[inside] += 0.01 * toward
    ground += GROUND_REACH * toward
    ground3 = np.column_stack([ground, np.full(len(ground), scene.ground_height)])
    return view_limits(np.vstack([pts, ground3]), view, margin=FRAME_MARGIN)


def _object_points(dynamic, objects):
    """Points that bound each dynamic object over its track (centre +- its size in every axis)."""
    out = []
    for name, track in objects.items():
        if name not in dynamic:
            continue
        d = dynamic[name].dims
        r = float(d.get("radius", 0.0)) + 0.5 * float(d.get("length", 0.0)) + 0.5 * float(np.linalg.norm(d.get("size", 0.0)))
        centres = np.array([pose[:3] for _, pose in track])
        out.append(np.vstack([centres + r * e for e in np.vstack([np.eye(3), -np.eye(3)])]))
    return np.vstack(out) if out else np.zeros((0, 3))


def render_preview(bag_dir, out_dir, scene_file=None, strip_frames=6, gif_frames=40):
    """Write preview.png (key-frame strip) and preview.gif; returns their paths ([] if no skin).

    Every panel and every GIF frame is drawn from the same camera (CAMERA_VIEW, framed once by
    `camera_frame`), with the static objects and the ground.
    """
    from PIL import Image

    from softhand_sim.handmodel.render import draw_scene, plt

    out_dir = Path(out_dir)
    skins, objects = read_frames(bag_dir, max_frames=gif_frames)
    if not skins:
        return []
    scene = load_scene(scene_file)
    dynamic = {o.name: o for o in scene.dynamic_objects}
    all_pts = np.concatenate([s for _, s, in skins])
    center = 0.5 * (all_pts.min(axis=0) + all_pts.max(axis=0))
    backdrop = backdrop_meshes(scene, center)
    limits = camera_frame(scene, np.vstack([all_pts, _object_points(dynamic, objects)]))
    aspect = (limits[1][1] - limits[1][0]) / (limits[0][1] - limits[0][0])  # height / width
    t0 = skins[0][0]

    def draw(ax, k):
        t, pts = skins[k]
        objs = [(dynamic[n].shape, dynamic[n].dims, _pose_at(track, t)) for n, track in objects.items()
                if n in dynamic]
        draw_scene(ax, pts, np.arange(len(pts)).reshape(-1, 3), objs, view=CAMERA_VIEW, extra_meshes=backdrop,
                   limits=limits)
        ax.set_title(f"t = {t - t0:.1f} s", fontsize=9)

    keys = np.linspace(0, len(skins) - 1, min(strip_frames, len(skins))).round().astype(int)
    fig, axes = plt.subplots(1, len(keys), figsize=(PANEL_WIDTH_IN * len(keys), PANEL_WIDTH_IN * aspect + 0.3),
                             dpi=90, squeeze=False)
    for ax, k in zip(axes[0], keys):
        draw(ax, k)
    fig.tight_layout()
    png = out_dir / "preview.png"
    fig.savefig(png)
    plt.close(fig)

    frames = []
    for k in range(len(skins)):
        fig, ax = plt.subplots(figsize=(GIF_WIDTH_IN, GIF_WIDTH_IN * aspect + 0.3), dpi=80)
        draw(ax, k)
        fig.tight_layout(pad=0.2)
        fig.canvas.draw()
        frames.append(Image.fromarray(np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()))
        plt.close(fig)
    gif = out_dir / "preview.gif"
    frames[0].save(gif, save_all=True, append_images=frames[1:], duration=125, loop=0)
    return [str(png), str(gif)]
