"""Render meshes: crease-aware corner normals, face planes, packing several meshes into one."""

from __future__ import annotations

import numpy as np
import torch
import trimesh

from bop_cender.render.mesh import pack_meshes, prepare_mesh


def test_corner_normals_are_smooth_within_the_crease_angle_only() -> None:
    cylinder = trimesh.creation.cylinder(radius=15, height=40, sections=24)  # 15 degrees between facets
    smooth = prepare_mesh(cylinder, 30.0).corner_normals.numpy()
    flat = prepare_mesh(cylinder, 0.0).corner_normals.numpy()
    side = np.abs(cylinder.face_normals[:, 2]) < 0.5
    corners = cylinder.vertices[cylinder.faces[side]]
    radial = corners * np.array([1, 1, 0])
    radial /= np.linalg.norm(radial, axis=2, keepdims=True)
    assert np.abs(smooth[side] - radial).max() < 1e-5  # side corners point radially
    assert np.abs(smooth[~side] - cylinder.face_normals[~side][:, None]).max() < 1e-5  # caps stay flat
    assert np.abs(flat - cylinder.face_normals[:, None]).max() < 1e-5
    coarse = trimesh.creation.cylinder(radius=15, height=40, sections=8)  # 45 degrees: beyond 30, sharp
    normals = prepare_mesh(coarse, 30.0).corner_normals.numpy()
    assert np.abs(normals - coarse.face_normals[:, None]).max() < 1e-5


def test_repeated_vertices_are_smoothed_as_one_and_positions_kept() -> None:
    cylinder = trimesh.creation.cylinder(radius=15, height=40, sections=24)
    unmerged = trimesh.Trimesh(
        cylinder.triangles.reshape(-1, 3), np.arange(3 * len(cylinder.faces)).reshape(-1, 3), process=False
    )  # every face has its own three vertices, as in many PLYs
    a = prepare_mesh(cylinder)
    b = prepare_mesh(unmerged)
    assert torch.allclose(a.corner_normals, b.corner_normals, atol=1e-6)
    assert torch.equal(b.vertices, torch.tensor(np.array(unmerged.vertices), dtype=torch.float32))
    assert abs(a.radius - np.linalg.norm(cylinder.vertices, axis=1).max()) < 1e-9


def test_face_planes_and_packing() -> None:
    box = trimesh.creation.box((4, 6, 8))
    mesh = prepare_mesh(box)
    planes = mesh.face_planes.numpy()
    assert np.allclose(planes[:, :3], box.face_normals, atol=1e-6)
    assert np.allclose(planes[:, 3], np.einsum("ij,ij->i", box.face_normals, box.triangles[:, 0]), atol=1e-5)
    other = prepare_mesh(trimesh.creation.icosphere(subdivisions=1))
    packed = pack_meshes([mesh, other, mesh])
    F, N = mesh.num_faces, mesh.vertices.shape[0]
    assert packed.num_meshes == 3 and packed.faces.shape[0] == 2 * F + other.num_faces
    assert torch.equal(packed.faces[F : F + other.num_faces], other.faces + N)
    assert torch.equal(
        packed.face_instance, torch.repeat_interleave(torch.arange(3), torch.tensor([F, other.num_faces, F]))
    )
    assert torch.equal(packed.face_local[-F:], torch.arange(F))
    assert torch.equal(packed.vertices[packed.faces[-1]], mesh.vertices[mesh.faces[-1]])
