import numpy as np
import trimesh

from bop_cender.data.bop_io import load_ply, save_ply
from bop_cender.data.ply_ascii import ascii_mesh


def test_ascii_mesh_equals_trimesh(tmp_path):
    mesh = trimesh.creation.cylinder(radius=12.345678, height=30.0, sections=17)
    save_ply(tmp_path / "obj_000001.ply", mesh)
    arrays = ascii_mesh(tmp_path / "obj_000001.ply")
    reference = load_ply(tmp_path / "obj_000001.ply")
    assert arrays is not None
    np.testing.assert_array_equal(arrays.faces, reference.faces)
    # What the renderer uses (float32) is identical; the float64 parse is the toolkit's reading.
    np.testing.assert_array_equal(arrays.vertices.astype(np.float32), np.asarray(reference.vertices, np.float32))


def test_binary_ply_is_left_to_trimesh(tmp_path):
    save_ply(tmp_path / "obj_000002.ply", trimesh.creation.box((1.0, 2.0, 3.0)), binary=True)
    assert ascii_mesh(tmp_path / "obj_000002.ply") is None


def test_non_triangle_faces_are_left_to_trimesh(tmp_path):
    (tmp_path / "quad.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n"
    )
    assert ascii_mesh(tmp_path / "quad.ply") is None
