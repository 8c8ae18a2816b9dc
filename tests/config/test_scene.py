"""The scene file: default scene as specified, inertia from shape, clear errors on bad input."""
import numpy as np
import pytest

from softhand_sim.scene import DEFAULT_FRICTION, SceneError, load_scene, shape_inertia


def test_default_scene():
    """Ground, a table-height static box, a 0.1 kg ball of ~4 cm radius, a small box and a mug, mu 0.5."""
    scene = load_scene()
    assert scene.ground_height == 0.0
    table = scene.object("table")
    assert table.static and table.shape == "box"
    assert 0.7 <= table.pose[2] + table.dims["size"][2] / 2 <= 0.8
    ball = scene.object("ball")
    assert ball.shape == "sphere" and ball.mass == 0.1 and abs(ball.dims["radius"] - 0.04) < 0.005
    assert {o.shape for o in scene.dynamic_objects} >= {"sphere", "box", "cylinder"}
    assert all(o.friction == 0.5 for o in scene.objects)
    # the two-hand box (issue #18): ~30 x 20 x 10 cm, 0.6 kg, too big for one hand
    big = scene.object("big_box")
    assert big.shape == "box" and big.mass == 0.6 and sorted(big.dims["size"]) == [0.10, 0.20, 0.30]
    # ... and clear of the ball and of the other objects (8 cm at least, footprints on the table)
    def footprint(o):
        r = np.full(2, o.dims["radius"]) if "radius" in o.dims else 0.5 * np.asarray(o.dims["size"][:2])
        return o.pose[:2] - r, o.pose[:2] + r
    blo, bhi = footprint(big)
    for o in scene.dynamic_objects:
        if o is not big:
            lo, hi = footprint(o)
            assert np.max(np.maximum(lo - bhi, blo - hi)) >= 0.07, o.name
    # every dynamic object starts resting on the table top (not inside it, not floating)
    top = table.pose[2] + table.dims["size"][2] / 2
    for o in scene.dynamic_objects:
        half = {"sphere": o.dims.get("radius"), "box": o.dims.get("size", (0, 0, 0))[2] / 2,
                "cylinder": o.dims.get("length", 0) / 2}[o.shape]
        assert abs(o.pose[2] - half - top) < 1e-6, o.name


def test_friction_is_the_scenes(tmp_path):
    """Each object's and the ground's Coulomb mu is its scene entry, DEFAULT_FRICTION where the
    entry has none (no node parameter overrides it: hand and engine read the same file)."""
    path = tmp_path / "scene.yaml"
    path.write_text("ground: {height: 0.0}\nobjects:\n"
                    "  - {name: a, shape: sphere, radius: 0.02, mass: 0.1}\n"
                    "  - {name: b, shape: sphere, radius: 0.02, mass: 0.1, friction: 0.8}\n")
    scene = load_scene(path)
    assert scene.ground_friction == DEFAULT_FRICTION == 0.5
    assert scene.object("a").friction == DEFAULT_FRICTION and scene.object("b").friction == 0.8


def test_inertia_against_formulae():
    """Sphere 2/5 m r^2; box m/12 (b^2 + c^2); capsule between its inscribed cylinder and bounding box."""
    assert np.allclose(shape_inertia("sphere", {"radius": 0.1}, 2.0), np.eye(3) * 0.4 * 2.0 * 0.01)
    box = shape_inertia("box", {"size": (1.0, 2.0, 3.0)}, 12.0)
    assert np.allclose(np.diag(box), [13.0, 10.0, 5.0])
    cap = shape_inertia("capsule", {"radius": 0.02, "length": 0.1}, 0.1)
    cyl = shape_inertia("cylinder", {"radius": 0.02, "length": 0.1}, 0.1)
    assert cap[0, 0] > cyl[0, 0] * 0.9 and cap[2, 2] < cyl[2, 2] * 1.01


@pytest.mark.parametrize(
    "text,words",
    [
        ("objects:\n  - {name: a, shape: cone, radius: 1}\n", ["'a'", "cone"]),
        ("objects:\n  - {name: b, shape: sphere, radius: -0.1, mass: 1}\n", ["'b'", "radius", "-0.1"]),
        ("objects:\n  - {name: c, shape: sphere, radius: 0.1, mass: 0}\n", ["'c'", "mass"]),
        ("objects:\n  - {name: d, shape: mesh, file: nothere.stl}\n", ["'d'", "not found"]),
        ("objects:\n  - {name: e, shape: sphere, radius: 0.1, colour: red}\n", ["'e'", "colour"]),
        ("objects:\n  - {name: f, shape: box, size: [1, 2]}\n", ["'f'", "size"]),
    ],
)
def test_bad_scene_refused(tmp_path, text, words):
    """Each bad scene is refused with a message naming the object and the bad key or value."""
    path = tmp_path / "scene.yaml"
    path.write_text(text)
    with pytest.raises(SceneError) as err:
        load_scene(path)
    for w in words:
        assert w in str(err.value)


def test_missing_scene_file(tmp_path):
    with pytest.raises(SceneError, match="not found"):
        load_scene(tmp_path / "nope.yaml")
