"""Spatial clusters of skin points for the self-contact broad phase (self_contact.py): a
segment's skin points in groups of at most CLUSTER_SIZE that lie close together at rest, so one
test of a cluster's current bounding box skips most points far from another segment, however
the skin has deformed since rest."""
import numpy as np

CLUSTER_SIZE = 32


def spatial_clusters(points, size=CLUSTER_SIZE):
    """Index lists (into points (P,3)) of spatially compact clusters of at most `size` points:
    recursive median split along the longest side of the bounding box."""
    out, todo = [], [np.arange(len(points))]
    while todo:
        idx = todo.pop()
        if len(idx) <= size:
            out.append(idx)
            continue
        pts = points[idx]
        axis = int(np.argmax(pts.max(axis=0) - pts.min(axis=0)))
        order = idx[np.argsort(pts[:, axis], kind="stable")]
        half = len(order) // 2
        todo += [order[half:], order[:half]]
    return out

