"""The renderer's CUDA kernel (``bop_cender.render.cuda_render``): the CPU's compiled maps, one launch a call.

Without a GPU the kernel runs in numba's CUDA simulator (a subprocess with ``NUMBA_ENABLE_CUDASIM=1``: every CUDA
thread a Python thread, the shared device functions the CPU's plain Python ones), where it must give the CPU's
compiled render (packed meshes, exact keys: ``render_compiled``) bit for bit: a pile of parts that occlude each
other (an L-bracket among them), parts cut by the frame, windows at an origin, canvases in several launches; a
vertex behind the near plane leaves the call to the torch pipeline (None). On a GPU (``-m cuda``) ``render_scene``
takes it by default and ``tests/render/test_rasterizer.py`` checks its maps against ray casting.
"""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from bop_cender.render.mesh import pack_meshes, prepare_mesh

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
from cuda_simulator import simulated_ok_lines  # noqa: E402

#: What the simulated run checks, printed line by line ("ok ...") for the test to read.
_SIMULATED = textwrap.dedent(
    """
    import sys
    sys.path[:0] = [{tests!r} + "/render"]
    import numpy as np, torch, trimesh
    from reference import K_matrix, bracket
    from test_compiled_raster import _poses
    from bop_cender.render import cuda_render
    from bop_cender.render.compiled_raster import render_compiled
    from bop_cender.render.mesh import pack_meshes, prepare_mesh

    H, W = 40, 56
    K = K_matrix(120.0, 118.0, 27.3, 19.6)
    meshes = [prepare_mesh(bracket()), prepare_mesh(trimesh.creation.box((40.0, 30.0, 20.0))),
              prepare_mesh(trimesh.creation.icosphere(subdivisions=1, radius=15.0))]
    packed = pack_meshes(meshes)
    T = torch.as_tensor(_poses(3, 3, seed=5, spread=25.0), dtype=torch.float32)  # (V, M, 4, 4): a pile per view
    R, t = T[..., :3, :3], T[..., :3, 3]
    Ks = torch.as_tensor(np.repeat(K[None], 3, 0), dtype=torch.float32)
    offsets = torch.tensor([[0, 0], [5, 9], [-4, 30]])  # windows: the frame, inside it, cut by its border
    for name, size, origins, launch_pixels in (("frame", (H, W), None, 1 << 25), ("windows", (24, 30), offsets, 800)):
        cuda_render.CHUNK_PIXELS = launch_pixels  # 800: a canvas per launch
        cpu = render_compiled(packed, R, t, Ks, *size, 1.0, origins)
        sim = cuda_render.cuda_render(packed, R, t, Ks, *size, 1.0, origins, threads=8)
        same = [bool(torch.equal(a, b)) for a, b in zip(cpu, sim)]
        print("ok", name, same, int((cpu[2] >= 0).sum()), len(torch.unique(cpu[2][cpu[2] >= 0] >= meshes[0].num_faces)))
    T_near = T.clone()
    T_near[0, 0, 2, 3] = 5.0  # a vertex behind the near plane
    print("ok near", cuda_render.cuda_render(packed, T_near[..., :3, :3], T_near[..., :3, 3], Ks, H, W, 1.0,
                                             threads=8) is None)
    empty = cuda_render.cuda_render(packed, R[:0], t[:0], Ks[:0], H, W, 1.0, threads=8)
    print("ok empty", [tuple(x.shape) for x in empty])
    for threads in (0, 3, 1024):
        try:
            cuda_render.cuda_render(packed, R, t, Ks, H, W, 1.0, threads=threads)
        except ValueError as error:
            print("ok threads", threads, error)
    """
)


def test_the_kernel_gives_the_cpu_maps_bit_for_bit_in_numbas_cuda_simulator() -> None:
    lines = simulated_ok_lines(_SIMULATED)
    assert [line.split()[1] for line in lines] == ["frame", "windows", "near", "empty", "threads", "threads", "threads"]
    for line in lines[:2]:
        assert "[True, True, True]" in line, line  # depth, normals, face ids: the CPU's bits
        covered, parts = (int(x) for x in line.rsplit(" ", 2)[1:])
        assert covered > 100 and parts == 2, line  # drawn, by the bracket and by the other parts
    assert lines[2].endswith("True")
    assert lines[3] == "ok empty [(0, 40, 56), (0, 40, 56, 3), (0, 40, 56)]"


def test_the_kernel_refuses_cpu_tensors_outside_the_simulator() -> None:
    from bop_cender.render.cuda_loops import simulator_enabled
    from bop_cender.render.cuda_render import cuda_render

    if simulator_enabled():
        pytest.skip("the simulator takes CPU tensors")
    packed = pack_meshes([prepare_mesh(trimesh.creation.box((40.0, 30.0, 20.0)))])
    with pytest.raises(ValueError, match="CUDA tensors"):
        cuda_render(packed, torch.eye(3)[None, None], torch.zeros(1, 1, 3), torch.eye(3)[None], 8, 8, 1.0)


def test_render_scene_on_cuda_goes_through_the_kernels_guard(monkeypatch, kernel_standing) -> None:
    """On CUDA the ``auto`` and ``numba`` render backends take the kernel where it runs; where it declines a call (a
    vertex behind the near plane) both take the torch pipeline with one warning; where numba's CUDA target is
    missing, ``auto`` warns once and takes the torch pipeline, ``numba`` says why it cannot run (the guard's rules,
    ``tests/render/test_kernel_guard.py``)."""
    import types

    from bop_cender.render import cuda_render
    from bop_cender.render.backend import NumbaRender

    maps, pipeline = (torch.zeros(1), torch.zeros(1), torch.zeros(1)), (torch.ones(1), torch.ones(1), torch.ones(1))
    auto, numba = NumbaRender(), NumbaRender(insist=True)
    for backend in (auto, numba):  # the torch pipeline, stood in for: the canvases below have no data
        backend.torch = types.SimpleNamespace(scene_maps=lambda *a: pipeline)
    R = types.SimpleNamespace(device=torch.device("cuda"), shape=(2, 1, 3, 3))  # what the dispatch reads
    args = (None, R, None, None, 8, 8, 1.0)
    kernel_standing(cuda_render.GUARD)
    monkeypatch.setattr(cuda_render, "cuda_render", lambda *a: maps)
    assert auto.scene_maps(*args) is maps is numba.scene_maps(*args)
    monkeypatch.setattr(cuda_render, "cuda_render", lambda *a: None)  # declined: the near plane
    for backend in (auto, numba):
        with pytest.warns(RuntimeWarning, match="render_scene's CUDA kernel leaves geometry behind the near plane"):
            assert backend.scene_maps(*args) is pipeline
    kernel_standing(cuda_render.GUARD, "numba.cuda finds no CUDA driver")
    with pytest.raises(
        RuntimeError, match="needs the CUDA render kernel, which cannot run here: numba.cuda finds no CUDA driver"
    ):
        numba.scene_maps(*args)
    with pytest.warns(RuntimeWarning, match="torch pipeline on CUDA: numba.cuda finds no CUDA driver"):
        assert auto.scene_maps(*args) is pipeline


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_on_cuda_render_scene_takes_the_kernel_and_gives_the_cpu_maps() -> None:
    try:
        from tests.render.reference import K_matrix, bracket
        from tests.render.test_compiled_raster import _poses
    except ImportError:
        sys.path[:0] = [str(ROOT / "tests" / "render")]
        from reference import K_matrix, bracket
        from test_compiled_raster import _poses
    from bop_cender.render.backend import render_backend_named
    from bop_cender.render.cuda_loops import cuda_unavailable_reason
    from bop_cender.render.rasterizer import render_scene

    if cuda_unavailable_reason() is not None:
        pytest.skip(cuda_unavailable_reason())
    meshes = [prepare_mesh(bracket()), prepare_mesh(trimesh.creation.box((40.0, 30.0, 20.0)))]
    T = torch.as_tensor(_poses(4, 2, seed=3), dtype=torch.float32)
    Ks = torch.as_tensor(np.repeat(K_matrix(300.0, 295.0, 64.3, 47.6)[None], 4, 0), dtype=torch.float32)
    cpu = render_scene(meshes, T, Ks, 96, 128)
    on_cuda = [m.to("cuda") for m in meshes]
    kernel = render_scene(on_cuda, T.cuda(), Ks.cuda(), 96, 128)
    numba, torch_pipeline = render_backend_named("numba"), render_backend_named("torch")
    assert torch.equal(
        kernel.packed_face, render_scene(on_cuda, T.cuda(), Ks.cuda(), 96, 128, backend=numba).packed_face
    )
    pipeline = render_scene(on_cuda, T.cuda(), Ks.cuda(), 96, 128, backend=torch_pipeline)
    for other in (cpu, pipeline):  # float32 rounding apart: a pixel where two faces nearly tie may differ
        assert (kernel.packed_face.cpu() != other.packed_face.cpu()).float().mean() < 1e-3
        same = kernel.packed_face.cpu() == other.packed_face.cpu()
        torch.testing.assert_close(kernel.depth.cpu()[same], other.depth.cpu()[same], rtol=1e-5, atol=1e-4)
        torch.testing.assert_close(kernel.normals.cpu()[same], other.normals.cpu()[same], rtol=1e-4, atol=1e-4)
