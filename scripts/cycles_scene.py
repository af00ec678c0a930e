"""The Blender scene of ``scripts/rerender_cycles.py``: a dataset scene's GT objects under a drawn :class:`Look`,
path traced by Cycles on the CPU.

Not a command. Needs ``bpy`` (``pip install bpy==4.2.0``, Python 3.11; the ``cycles`` extra), imported when a
:class:`CyclesScene` is made. One Blender scene serves every image: the models' meshes are made once, the
materials, lights, world and ground plane again per dataset scene, the camera per image.
"""

from __future__ import annotations

import importlib
import math
import os
import sys
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from cycles_look import CV_TO_BLENDER, MM, Lamp, Look, blender_camera, support_plane, up_frame
from PIL import Image

from bop_cender.meshes import MeshCache

#: Ground plane edge, metres: far past any view's border.
PLANE_SIZE = 20.0
#: Sharp edges: faces meeting at more than this angle are not smoothed across (the model's creases).
SMOOTH_ANGLE = math.radians(30.0)


class CyclesScene:
    """Cycles set up once (samples, threads, denoiser, colour management, the object-index pass), then filled per
    dataset scene (:meth:`set_scene`) and rendered per view (:meth:`render`).

    Args:
        models: the dataset's models by obj_id (``is_target`` False: a carrier).
        layout: ``dimo`` or ``tless`` (which material the targets get is in the :class:`Look`).
        samples: Cycles samples per pixel (adaptive sampling may stop earlier).
        threads: CPU threads (0: all).
        denoise: OpenImageDenoise on the result (only where the wheel has it: :func:`denoiser_available`).
        work: a folder for the render's temporary files (the image, the object index).
    """

    def __init__(self, models: Mapping[int, Any], samples: int, threads: int, denoise: bool, work: Path) -> None:
        import bpy

        self.bpy = bpy
        self.models = models
        self.meshes = MeshCache(models)
        self.work = Path(work)
        with quiet_stdout():
            bpy.ops.wm.read_factory_settings(use_empty=True)
        self.scene = bpy.context.scene
        self._configure(samples, threads, denoise)
        self._blender_meshes: dict[int, Any] = {}
        self._per_scene: list[Any] = []  # datablocks of the current dataset scene, removed by the next
        self.camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
        self.scene.collection.objects.link(self.camera)
        self.scene.camera = self.camera
        self.camera.data.sensor_fit = "HORIZONTAL"
        self.camera.data.clip_start, self.camera.data.clip_end = 1e-3, 1e3

    def _configure(self, samples: int, threads: int, denoise: bool) -> None:
        sc = self.scene
        sc.render.engine = "CYCLES"
        cy = sc.cycles
        cy.device = "CPU"
        cy.samples = samples
        cy.use_adaptive_sampling = True
        cy.use_animated_seed = False
        cy.use_denoising = denoise
        if denoise:
            cy.denoiser = "OPENIMAGEDENOISE"
            cy.denoising_input_passes = "RGB_ALBEDO_NORMAL"
            cy.denoising_prefilter = "ACCURATE"
        cy.max_bounces, cy.diffuse_bounces, cy.glossy_bounces = 4, 2, 3  # metal sees metal; a CPU budget
        cy.transmission_bounces, cy.volume_bounces, cy.transparent_max_bounces = 0, 0, 2
        cy.caustics_reflective = cy.caustics_refractive = False
        cy.sample_clamp_indirect = 10.0
        sc.render.threads_mode = "FIXED" if threads else "AUTO"
        if threads:
            sc.render.threads = threads
        sc.render.use_persistent_data = True  # the scene's BVH is kept between its views
        sc.render.resolution_percentage = 100
        sc.render.dither_intensity = 0.0
        sc.render.image_settings.file_format = "PNG"
        sc.render.image_settings.color_mode = "RGB"
        sc.render.image_settings.color_depth = "8"
        sc.view_settings.view_transform = "AgX"
        sc.view_layers[0].use_pass_object_index = True
        # the compositor passes the image through and writes the object index, a float EXR (read by render())
        sc.use_nodes = True
        tree = sc.node_tree
        tree.nodes.clear()
        layers = tree.nodes.new("CompositorNodeRLayers")
        tree.links.new(layers.outputs["Image"], tree.nodes.new("CompositorNodeComposite").inputs["Image"])
        index = tree.nodes.new("CompositorNodeOutputFile")
        index.base_path = str(self.work)
        index.format.file_format, index.format.color_mode, index.format.color_depth = "OPEN_EXR", "RGB", "32"
        index.file_slots[0].path = "index"
        tree.links.new(layers.outputs["IndexOB"], index.inputs[0])
        self._index_path = self.work / f"index{sc.frame_current:04d}.exr"

    def set_scene(self, scene: Any, look: Look) -> None:
        """Put ``scene``'s GT objects at their poses (``scene.gt[i]`` gets object index ``i + 1``), the ground plane
        under them, the world and the lamps of ``look``; the previous scene's go."""
        bpy = self.bpy
        for block in self._per_scene:
            collection = {"OBJECT": bpy.data.objects, "MATERIAL": bpy.data.materials, "LIGHT": bpy.data.lights,
                          "WORLD": bpy.data.worlds, "MESH": bpy.data.meshes}[block.id_type]  # fmt: skip
            collection.remove(block)
        self._per_scene = []
        target, carrier = _target_material(bpy, look), _carrier_material(bpy, look)
        self._per_scene += [target, carrier]
        points = []
        for i, g in enumerate(scene.gt):
            mesh = self._mesh(g.obj_id)
            mesh.materials[0] = target if self.models[g.obj_id].is_target else carrier
            obj = bpy.data.objects.new(f"gt{i}", mesh)
            obj.matrix_world = _matrix(g.T_world_model)
            obj.pass_index = i + 1
            self.scene.collection.objects.link(obj)
            self._per_scene.append(obj)
            vertices = self.meshes.arrays(g.obj_id).vertices
            points.append(vertices @ g.T_world_model[:3, :3].T + g.T_world_model[:3, 3])
        points = np.concatenate(points)
        eyes = np.stack([np.linalg.inv(v.T_cam_world)[:3, 3] for v in scene.views])
        plane = support_plane(points, eyes)
        if plane is None:  # cameras all around: no ground, up against the mean viewing direction
            axes = np.stack([np.linalg.inv(v.T_cam_world)[:3, 2] for v in scene.views])
            centre, up = points.mean(axis=0), -axes.mean(axis=0)
        else:
            centre, up = plane
            self._add_plane(centre, up, look)
        frame = up_frame(up)
        centre = centre + frame[:, 2] * (points @ frame[:, 2] - centre @ frame[:, 2]).max() / 2  # mid-height
        self._per_scene.append(_world(bpy, self.scene, look, frame))
        for k, lamp in enumerate(look.lamps):
            self._add_lamp(k, lamp, centre, frame)
        self.scene.view_settings.exposure = look.exposure

    def render(self, view: Any, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """``view`` of the current scene: ``(rgb (H, W, 3) uint8, index (H, W) int)``, index ``i + 1`` where
        ``scene.gt[i]`` is seen (the loader's order: a T-LESS image's own ``scene_gt`` order is ``gt_ids``), 0 on the
        ground and the sky. Raises :class:`cycles_look.SkewError`."""
        settings = blender_camera(view.K, int(view.width), int(view.height))
        render = self.scene.render
        render.resolution_x, render.resolution_y = int(view.width), int(view.height)
        render.pixel_aspect_x, render.pixel_aspect_y = settings.pop("pixel_aspect_x"), settings.pop("pixel_aspect_y")
        for name, value in settings.items():
            setattr(self.camera.data, name, value)
        self.camera.matrix_world = _matrix(np.linalg.inv(view.T_cam_world) @ CV_TO_BLENDER)
        self.scene.cycles.seed = seed
        path = self.work / "render.png"
        render_to(self.bpy, path)
        with Image.open(path) as image:
            rgb = np.asarray(image.convert("RGB"))
        image = self.bpy.data.images.load(str(self._index_path))
        pixels = np.empty(len(image.pixels), dtype=np.float32)
        image.pixels.foreach_get(pixels)  # bottom row first
        self.bpy.data.images.remove(image)
        index = np.rint(pixels.reshape(int(view.height), int(view.width), 4)[::-1, :, 0]).astype(np.int64)
        return rgb, index

    def _mesh(self, obj_id: int) -> Any:
        """The model as a Blender mesh (metres), smooth but for creases, one material slot; made once."""
        if obj_id not in self._blender_meshes:
            arrays = self.meshes.arrays(obj_id)
            faces = np.asarray(arrays.faces, dtype=np.int32)
            mesh = self.bpy.data.meshes.new(f"obj_{obj_id:06d}")
            mesh.vertices.add(len(arrays.vertices))
            mesh.vertices.foreach_set("co", (np.asarray(arrays.vertices) * MM).astype(np.float32).ravel())
            mesh.loops.add(faces.size)
            mesh.loops.foreach_set("vertex_index", faces.ravel())
            mesh.polygons.add(len(faces))
            mesh.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
            mesh.update(calc_edges=True)
            mesh.shade_smooth()
            mesh.set_sharp_from_angle(angle=SMOOTH_ANGLE)
            mesh.materials.append(None)
            self._blender_meshes[obj_id] = mesh
        return self._blender_meshes[obj_id]

    def _add_plane(self, point: np.ndarray, up: np.ndarray, look: Look) -> None:
        bpy = self.bpy
        h = PLANE_SIZE / 2
        mesh = bpy.data.meshes.new("ground")
        mesh.from_pydata([(-h, -h, 0.0), (h, -h, 0.0), (h, h, 0.0), (-h, h, 0.0)], [], [(0, 1, 2, 3)])
        mesh.materials.append(_table_material(bpy, look))
        obj = bpy.data.objects.new("ground", mesh)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = up_frame(up), point
        obj.matrix_world = _matrix(T)
        self.scene.collection.objects.link(obj)
        self._per_scene += [obj, mesh, mesh.materials[0]]

    def _add_lamp(self, k: int, lamp: Lamp, centre: np.ndarray, frame: np.ndarray) -> None:
        """An area light at the lamp's direction and distance from ``centre`` (mm), facing it."""
        bpy = self.bpy
        light = bpy.data.lights.new(f"lamp{k}", "AREA")
        light.shape = "DISK" if lamp.disk else "SQUARE"
        light.size, light.energy = lamp.size, lamp.power
        light.use_nodes = True
        nodes, links = light.node_tree.nodes, light.node_tree.links
        blackbody = nodes.new("ShaderNodeBlackbody")
        blackbody.inputs["Temperature"].default_value = lamp.kelvin
        links.new(blackbody.outputs["Color"], nodes["Emission"].inputs["Color"])
        direction = frame @ np.array([
            math.cos(lamp.elevation) * math.cos(lamp.azimuth),
            math.cos(lamp.elevation) * math.sin(lamp.azimuth),
            math.sin(lamp.elevation),
        ])  # fmt: skip
        obj = bpy.data.objects.new(f"lamp{k}", light)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = up_frame(direction), centre + lamp.distance / MM * direction  # its -z: to the pile
        obj.matrix_world = _matrix(T)
        self.scene.collection.objects.link(obj)
        self._per_scene += [obj, light]


def denoiser_available() -> bool:
    """Whether this Blender was built with OpenImageDenoise (the PyPI wheels for x86-64 are)."""
    import bpy  # noqa: F401  (bpy loads Cycles' own module, _cycles: imported after it)

    return bool(getattr(importlib.import_module("_cycles"), "with_openimagedenoise", False))


@contextmanager
def quiet_stdout() -> Iterator[None]:
    """Blender's own lines (``Fra:1 Mem: ...``, ``Saved: ...``) written to file descriptor 1 go to /dev/null."""
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


def render_to(bpy: Any, path: Path) -> None:
    """Render the current Blender scene to ``path`` (the scene's file format), Blender's messages silenced."""
    bpy.context.scene.render.filepath = str(path)
    with quiet_stdout():
        bpy.ops.render.render(write_still=True)


def _matrix(T: np.ndarray) -> Any:
    """A ``(4, 4)`` rigid transform in mm as a Blender matrix in metres."""
    from mathutils import Matrix

    T = np.array(T, dtype=np.float64)
    T[:3, 3] *= MM
    return Matrix(T.tolist())


def _principled(bpy: Any, name: str) -> tuple[Any, Any, Any]:
    """A new material: (material, its node tree, its principled BSDF)."""
    material = bpy.data.materials.new(name)
    material.use_nodes = True
    return material, material.node_tree, material.node_tree.nodes["Principled BSDF"]


def _texture_coordinates(tree: Any, scale: tuple[float, float, float]) -> Any:
    """The object's own coordinates (metres) scaled: the vector socket textures read."""
    coords = tree.nodes.new("ShaderNodeTexCoord")
    mapping = tree.nodes.new("ShaderNodeMapping")
    mapping.inputs["Scale"].default_value = scale
    tree.links.new(coords.outputs["Object"], mapping.inputs["Vector"])
    return mapping.outputs["Vector"]


def _bump(tree: Any, height: Any, strength: float, distance: float, bsdf: Any) -> None:
    bump = tree.nodes.new("ShaderNodeBump")
    bump.inputs["Strength"].default_value = strength
    bump.inputs["Distance"].default_value = distance
    tree.links.new(height, bump.inputs["Height"])
    tree.links.new(bump.outputs["Normal"], bsdf.inputs["Normal"])


def _target_material(bpy: Any, look: Look) -> Any:
    """Metal (brushed: anisotropic, marks stretched along one axis; or rough) or plastic, with fine marks."""
    material, tree, bsdf = _principled(bpy, "target")
    bsdf.inputs["Base Color"].default_value = (*look.target_color, 1.0)
    bsdf.inputs["Metallic"].default_value = look.target_metallic
    bsdf.inputs["Roughness"].default_value = look.target_roughness
    bsdf.inputs["Anisotropic"].default_value = look.anisotropy
    bsdf.inputs["Anisotropic Rotation"].default_value = look.anisotropy_rotation
    if look.scratch > 0:
        stretch = (1.0, 0.03, 1.0) if look.anisotropy > 0 else (1.0, 1.0, 1.0)
        noise = tree.nodes.new("ShaderNodeTexNoise")
        noise.inputs["Scale"].default_value = 800.0
        noise.inputs["Detail"].default_value = 6.0
        tree.links.new(_texture_coordinates(tree, stretch), noise.inputs["Vector"])
        _bump(tree, noise.outputs["Fac"], look.scratch, 2e-4, bsdf)
    return material


def _carrier_material(bpy: Any, look: Look) -> Any:
    material, _, bsdf = _principled(bpy, "carrier")
    bsdf.inputs["Base Color"].default_value = (*look.carrier_color, 1.0)
    bsdf.inputs["Metallic"].default_value = 0.0
    bsdf.inputs["Roughness"].default_value = look.carrier_roughness
    return material


def _table_material(bpy: Any, look: Look) -> Any:
    """The ground plane: wood grain (a distorted wave), a checker mat or marbled stone (noise), lightly bumped."""
    material, tree, bsdf = _principled(bpy, "table")
    bsdf.inputs["Roughness"].default_value = look.table_roughness
    s = look.table_scale
    (c0, c1) = [(*c, 1.0) for c in look.table_colors]
    if look.table == "checker":
        texture = tree.nodes.new("ShaderNodeTexChecker")
        texture.inputs["Scale"].default_value = 1.0
        texture.inputs["Color1"].default_value, texture.inputs["Color2"].default_value = c0, c1
        tree.links.new(_texture_coordinates(tree, (s, s, s)), texture.inputs["Vector"])
        tree.links.new(texture.outputs["Color"], bsdf.inputs["Base Color"])
        return material
    if look.table == "wood":
        texture = tree.nodes.new("ShaderNodeTexWave")
        texture.bands_direction = "X"
        texture.inputs["Scale"].default_value = 1.0
        texture.inputs["Distortion"].default_value = 6.0
        texture.inputs["Detail"].default_value = 3.0
        vector = _texture_coordinates(tree, (3 * s, 0.3 * s, 3 * s))  # grain along y
    else:
        texture = tree.nodes.new("ShaderNodeTexNoise")
        texture.inputs["Scale"].default_value = 1.0
        texture.inputs["Detail"].default_value = 10.0
        texture.inputs["Distortion"].default_value = 1.5
        vector = _texture_coordinates(tree, (s, s, s))
    tree.links.new(vector, texture.inputs["Vector"])
    ramp = tree.nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color, ramp.color_ramp.elements[1].color = c0, c1
    ramp.color_ramp.elements[0].position, ramp.color_ramp.elements[1].position = 0.3, 0.7
    tree.links.new(texture.outputs["Fac"], ramp.inputs["Fac"])
    tree.links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    _bump(tree, texture.outputs["Fac"], 0.15, 1e-3, bsdf)
    return material


def _world(bpy: Any, scene: Any, look: Look, frame: np.ndarray) -> Any:
    """No HDRI: a physical sky (Nishita, no sun disc) or a ground-horizon-zenith gradient, with ``up`` its zenith."""
    from mathutils import Matrix

    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    world.cycles.sampling_method = "MANUAL"  # a smooth world: a coarse importance map (the automatic one: seconds)
    world.cycles.sample_map_resolution = 64
    tree = world.node_tree
    background = tree.nodes["Background"]
    background.inputs["Strength"].default_value = look.world_strength
    coords = tree.nodes.new("ShaderNodeTexCoord")
    mapping = tree.nodes.new("ShaderNodeMapping")
    mapping.inputs["Rotation"].default_value = Matrix(frame.T.tolist()).to_euler("XYZ")  # up -> +z
    tree.links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
    if look.sky:
        sky = tree.nodes.new("ShaderNodeTexSky")
        sky.sky_type, sky.sun_disc = "NISHITA", False
        sky.sun_elevation, sky.sun_rotation = look.sun_elevation, look.sun_rotation
        tree.links.new(mapping.outputs["Vector"], sky.inputs["Vector"])
        tree.links.new(sky.outputs["Color"], background.inputs["Color"])
    else:
        split = tree.nodes.new("ShaderNodeSeparateXYZ")
        tree.links.new(mapping.outputs["Vector"], split.inputs["Vector"])
        ramp = tree.nodes.new("ShaderNodeValToRGB")
        elements = ramp.color_ramp.elements
        elements.new(0.5)
        for element, position, colour in zip(elements, (0.0, 0.5, 1.0), look.sky_colors, strict=True):
            element.position, element.color = position, (*colour, 1.0)
        to_unit = tree.nodes.new("ShaderNodeMapRange")  # z in [-1, 1] -> [0, 1]
        to_unit.inputs["From Min"].default_value = -1.0
        tree.links.new(split.outputs["Z"], to_unit.inputs["Value"])
        tree.links.new(to_unit.outputs["Result"], ramp.inputs["Fac"])
        tree.links.new(ramp.outputs["Color"], background.inputs["Color"])
    scene.world = world
    return world
