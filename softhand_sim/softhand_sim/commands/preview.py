"""Preview of a recorded run: key frames drawn from the recording with the CPU renderer.

Reads /hand/skin_marker (the skin as a triangle list) and /world/object_states (engine-side
objects) from the rosbag2 directory, the static objects from the scene file, and draws them with
handmodel.render (matplotlib, painter's algorithm; no ROS, no GPU). Writes preview.png (a strip
of key frames, side view) and preview.gif (the run, downsampled, three-quarter view).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from softhand_sim.scene import load_scene

STRIP_VIEW = "side"
GIF_VIEW = (-65.0, 25.0)  # (azimuth, elevation) [deg]
TABLE_RGB = (0.78, 0.74, 0.68)
TABLE_CELL = 0.02  # [m] the table top is drawn as small quads so depth sorting stays right


def read_frames(bag_dir, max_frames=60):
    """[(t, vertices (3F,3), triangles (F,3)), ...] and {name: [(t, pose (7,))]} from the recording."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    skins, objects = [], {}
    with Reader(Path(bag_dir)) as reader:
        conns = [c for c in reader.connections if c.topic in ("/hand/skin_marker", "/world/object_states")]
        for conn, t_ns, raw in reader.messages(connections=conns):
            msg = store.deserialize_cdr(raw, conn.msgtype)
            t = t_ns * 1e-9
            if conn.topic == "/hand/skin_marker":
                pts = np.array([[p.x, p.y, p.z] for p in msg.points], dtype=np.float64)
                if pts.size and pts.shape[0] % 3 == 0:
                    skins.append((t, pts))
            elif msg.points:
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


def table_top_mesh(scene, center, half_width):
    """The top faces of static boxes near `center`, as a grid of small quads (vertices, faces)."""
    verts, faces = [], []
    for obj in scene.static_objects:
        if obj.shape != "box":
            continue
        sx, sy, sz = obj.dims["size"]
        top = obj.pose[2] + sz / 2
        x0, x1 = max(obj.pose[0] - sx / 2, center[0] - half_width), min(obj.pose[0] + sx / 2, center[0] + half_width)
        y0, y1 = max(obj.pose[1] - sy / 2, center[1] - half_width), min(obj.pose[1] + sy / 2, center[1] + half_width)
        if x1 <= x0 or y1 <= y0:
            continue
        xs = np.linspace(x0, x1, max(2, int((x1 - x0) / TABLE_CELL) + 1))
        ys = np.linspace(y0, y1, max(2, int((y1 - y0) / TABLE_CELL) + 1))
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        base = sum(len(v) for v in verts)
        verts.append(np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, top)]))
        nx, ny = len(xs), len(ys)
        idx = np.arange(nx * ny).reshape(nx, ny) + base
        a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
        faces.append(np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])]))
    if not verts:
        return None
    return np.concatenate(verts), np.concatenate(faces)


def render_preview(bag_dir, out_dir, scene_file=None, strip_frames=6, gif_frames=40):
    """Write preview.png (key-frame strip) and preview.gif; returns their paths ([] if no skin)."""
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
    table = table_top_mesh(scene, center, 0.2)
    extra = [(table[0], table[1], TABLE_RGB, 0.999)] if table is not None else []
    t0 = skins[0][0]

    def draw(ax, k, view):
        t, pts = skins[k]
        objs = [(dynamic[n].shape, dynamic[n].dims, _pose_at(track, t)) for n, track in objects.items()
                if n in dynamic]
        draw_scene(ax, pts, np.arange(len(pts)).reshape(-1, 3), objs, view=view, extra_meshes=extra)
        ax.set_title(f"t = {t - t0:.1f} s", fontsize=9)

    keys = np.linspace(0, len(skins) - 1, min(strip_frames, len(skins))).round().astype(int)
    fig, axes = plt.subplots(1, len(keys), figsize=(3.0 * len(keys), 3.0), dpi=90, squeeze=False)
    for ax, k in zip(axes[0], keys):
        draw(ax, k, STRIP_VIEW)
    fig.tight_layout()
    png = out_dir / "preview.png"
    fig.savefig(png)
    plt.close(fig)

    frames = []
    for k in range(len(skins)):
        fig, ax = plt.subplots(figsize=(3.2, 3.2), dpi=80)
        draw(ax, k, GIF_VIEW)
        fig.canvas.draw()
        frames.append(Image.fromarray(np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()))
        plt.close(fig)
    gif = out_dir / "preview.gif"
    frames[0].save(gif, save_all=True, append_images=frames[1:], duration=125, loop=0)
    return [str(png), str(gif)]
