"""Render a DIMO- or T-LESS-layout dataset's images again with another renderer (pyrender: OpenGL, PBR).

Why: issue 11 checks the method "on images rendered by another renderer". Our synthetic sets are all shaded
by our own torch renderer (`bop_cender/synth/imaging.py`); a network trained on them may have learnt that
renderer's look. This copies a dataset (every JSON, the models) and renders every image of one split again
with pyrender: each scene's objects (parts and carriers) at their GT poses, the view's intrinsics and
``T_cam_world``, DIMO's parts metallic and glossy, T-LESS's objects grey plastic, the carriers matt
cardboard brown, a key light at the camera and two lamps beside it, a flat background, sensor noise. The
copy is read by the same loader, unchanged; the oracle heatmaps ignore images, so it tests the network
(stage 1) and what follows from it.

    PYOPENGL_PLATFORM=egl python scripts/rerender_pyrender.py DATA/dimo_test DATA/dimo_test_pyrender --split sim
    bop-cender run --dataset dimo --data-root DATA/dimo_test_pyrender --split sim --workers 2 --score
    python scripts/rerender_pyrender.py DATA/tless_test DATA/tless_test_pyrender --dataset tless

Needs ``pip install pyrender2`` (the ``pyrender`` extra) and an OpenGL context without a display (EGL, e.g.
Mesa's llvmpipe: ``PYOPENGL_PLATFORM=egl``, the default here; or ``osmesa``). Deterministic per ``--seed``
(the noise); the rendering itself is whatever the OpenGL driver makes of it.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

#: OpenCV camera (x right, y down, z forward) to OpenGL camera (x right, y up, z backward).
_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


def main(argv: list[str] | None = None) -> int:
    from bop_cender.synth.relook import add_look_arguments

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_look_arguments(ap)
    ap.add_argument("--seed", type=int, default=0, help="draws the sensor noise")
    ap.add_argument("--noise", type=float, default=3.0, help="sensor noise, standard deviation in grey levels")
    args = ap.parse_args(argv)
    for flag, bad, expected in (("--noise", args.noise < 0, "0 or more"),
                                ("--limit-scenes", args.limit_scenes is not None and args.limit_scenes < 1, "1 or more")):  # fmt: skip
        if bad:
            print(f"error: {flag}: expected {expected}", file=sys.stderr)
            return 2
    try:
        import pyrender

        pyrender.OffscreenRenderer(8, 8).delete()  # an OpenGL context: EGL or OSMesa usually fails here, not at import
    except Exception as exc:  # ImportError, or an OpenGL platform that fails to load
        print(f"error: pyrender is not usable here ({exc}); pip install pyrender2 (the pyrender extra), and set "
              "PYOPENGL_PLATFORM=egl or osmesa", file=sys.stderr)  # fmt: skip
        return 2
    from bop_cender.errors import BopCenderError
    from bop_cender.synth.relook import DEFAULT_SPLIT, open_every_image, relook_split

    if args.dst.exists():
        print(f"error: {args.dst} exists; give a new folder", file=sys.stderr)
        return 2
    try:
        args.split = args.split or DEFAULT_SPLIT[args.dataset]
        dataset = open_every_image(args.dataset, args.src, args.split)  # no image of the copy keeps our look
    except BopCenderError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    renderer = _Renderer(dataset, np.random.default_rng(args.seed), args.noise)
    try:
        relook_split(dataset, args.src, args.dst, lambda scene, view, _name: np.asarray(renderer.render(scene, view)),
                     args.limit_scenes, lambda line: print(line, flush=True))  # fmt: skip
    except (BopCenderError, ValueError) as exc:  # relook_split leaves nothing half-written
        print(f"error: {exc}", file=sys.stderr)
        return 2
    keys = dataset.scene_keys[: args.limit_scenes]
    print(f"wrote {args.dst} ({len(keys)} scenes of split {args.split} rendered by pyrender)")
    return 0


class _Renderer:
    """pyrender scenes of a dataset's GT, one offscreen renderer per image size."""

    def __init__(self, dataset, rng: np.random.Generator, noise: float) -> None:
        self.dataset, self.rng, self.noise = dataset, rng, noise
        self.meshes: dict[int, object] = {}
        self.renderers: dict[tuple[int, int], object] = {}

    def mesh(self, obj_id: int):
        """The model as a pyrender mesh: smooth normals within 30 degrees (sharp creases stay sharp), metallic
        and glossy for DIMO's parts, grey plastic for T-LESS's objects, matt brown for the carriers."""
        import pyrender
        import trimesh

        if obj_id not in self.meshes:
            model = self.dataset.models[obj_id]
            tm = trimesh.load(model.path, force="mesh", process=True)
            tm = trimesh.graph.smooth_shade(tm, angle=np.radians(30.0))
            if model.is_target and self.dataset.name == "dimo":  # DIMO's parts: machined metal
                material = pyrender.MetallicRoughnessMaterial(
                    baseColorFactor=(0.85, 0.85, 0.88, 1.0), metallicFactor=0.6, roughnessFactor=0.3
                )
            elif model.is_target:  # T-LESS's objects: grey plastic
                material = pyrender.MetallicRoughnessMaterial(
                    baseColorFactor=(0.62, 0.6, 0.58, 1.0), metallicFactor=0.0, roughnessFactor=0.55
                )
            else:
                material = pyrender.MetallicRoughnessMaterial(
                    baseColorFactor=(0.55, 0.45, 0.33, 1.0), metallicFactor=0.0, roughnessFactor=0.8
                )
            self.meshes[obj_id] = pyrender.Mesh.from_trimesh(tm, material=material, smooth=True)
        return self.meshes[obj_id]

    def render(self, scene, view):
        """The RGB image (PIL) of ``view`` of ``scene``."""
        import pyrender
        from PIL import Image

        size = (int(view.width), int(view.height))
        if size not in self.renderers:
            self.renderers[size] = pyrender.OffscreenRenderer(*size)
        world = pyrender.Scene(bg_color=(0.18, 0.2, 0.22, 1.0), ambient_light=(0.12, 0.12, 0.12))
        for g in scene.gt:
            world.add(self.mesh(g.obj_id), pose=np.asarray(g.T_world_model, dtype=np.float64))
        K = np.asarray(view.K, dtype=np.float64)
        if abs(K[0, 1]) > 1e-6:  # pyrender's pinhole has no skew: the image would be sheared against the GT
            raise ValueError(f"{view.rgb_path}: K has skew {K[0, 1]:g}; pyrender cannot render a skewed camera")
        cam_pose = np.linalg.inv(np.asarray(view.T_cam_world, dtype=np.float64)) @ _CV_TO_GL
        camera = pyrender.IntrinsicsCamera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], znear=10.0, zfar=20000.0)
        world.add(camera, pose=cam_pose)
        world.add(pyrender.DirectionalLight(color=np.ones(3), intensity=2.0), pose=cam_pose)
        for dx in (-300.0, 300.0):  # two lamps beside and above the camera (in its OpenGL frame: x right, y up)
            offset = np.eye(4)
            offset[:3, 3] = (dx, 300.0, 0.0)
            world.add(pyrender.PointLight(color=np.ones(3), intensity=1.5e5), pose=cam_pose @ offset)
        color, _ = self.renderers[size].render(world)
        image = color.astype(np.float32) + self.rng.normal(0.0, self.noise, color.shape)
        return Image.fromarray(np.clip(np.rint(image), 0, 255).astype(np.uint8))


if __name__ == "__main__":
    sys.exit(main())
