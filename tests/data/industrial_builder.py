"""Write a small multi-sensor split in the BOP-Industrial layout (IPD, XYZ-IBD, ITODD-MV), for reader tests.

Importable by other tests: ``from tests.data.industrial_builder import build_industrial``.

What it writes under ``root`` for an :class:`~bop_cender.data.industrial_params.IndustrialSpec` (its sensors,
modalities, image sizes and suffix):

- ``models/``: ``models_info.json`` and ASCII PLYs (:mod:`tests.data.bop_builder`'s cylinder, box, tetrahedron);
- ``test/{scene:06d}/`` for scenes 1..n, each with static objects and per sensor ``s``: ``scene_camera_s.json``
  (``cam_K`` scaled to the sensor's size, ``cam_R_w2c``/``cam_t_w2c`` of a look-at camera, ``depth_scale``),
  ``scene_gt_s.json`` (``T_cam_world @ T_world_model``, rounded as T-LESS rounds), ``scene_gt_info_s.json``, and
  ``{modality}_s/`` images of the sensor's size (gray: one channel, rgb: three, depth: uint16), and with ``masks``
  ``mask_s/`` and ``mask_visib_s/``. The last sensor does not see the last object (it is left out of its
  ``scene_gt``), the second lists the objects in reverse order: association across sensors is by world pose;
- ``test_targets_bop19.json``: the evaluated sensor's images but image 0 of the last scene (BOP'19 rule).

The returned :class:`BuiltIndustrial` holds what the files were written from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from bop_cender.data.bop_io import save_depth, save_json, write_image
from bop_cender.data.industrial_params import IndustrialSpec
from bop_cender.data.types import Sensor

try:
    from tests.data.bop_builder import BopSpec, _look_at, _pose, _write_models, round_like_tless
except ImportError:  # pytest's default import mode puts tests/data itself on sys.path
    from bop_builder import BopSpec, _look_at, _pose, _write_models, round_like_tless

DEPTH_SCALE = 0.1


@dataclass
class BuiltIndustrial:
    """What a built split holds.

    Attributes:
        T_cam_world: per (scene folder, sensor, image id) ``(4, 4)`` as written (rounded).
        K: per (scene folder, sensor, image id) ``(3, 3)``.
        objects: per scene folder, ``[(obj_id, T_world_model)]`` (exact).
        gt_order: per (scene folder, sensor), the object indices in its ``scene_gt`` lists.
        visib: per (scene folder, sensor, image id), ``visib_fract`` per gt_id.
        targets: the entries of ``test_targets_bop19.json``.
    """

    root: Path
    spec: IndustrialSpec
    T_cam_world: dict[tuple[str, str, int], np.ndarray] = field(default_factory=dict)
    K: dict[tuple[str, str, int], np.ndarray] = field(default_factory=dict)
    objects: dict[str, list[tuple[int, np.ndarray]]] = field(default_factory=dict)
    gt_order: dict[tuple[str, str], list[int]] = field(default_factory=dict)
    visib: dict[tuple[str, str, int], list[float]] = field(default_factory=dict)
    targets: list[dict[str, int]] = field(default_factory=list)

    @property
    def split_dir(self) -> Path:
        return self.root / "test"


def build_industrial(
    root: str | Path,
    spec: IndustrialSpec,
    *,
    obj_ids: tuple[int, ...] = (1, 2),
    n_scenes: int = 2,
    n_images: int = 2,
    masks: bool = True,
    seed: int = 0,
) -> BuiltIndustrial:
    """Write the split (see the module docstring); same arguments, same files."""
    root = Path(root)
    rng = np.random.default_rng(seed)
    built = BuiltIndustrial(root, spec)
    _write_models(root, BopSpec(obj_ids=obj_ids, models_dirs=("models",)))
    for scene in range(1, n_scenes + 1):
        sid = f"{scene:06d}"
        objects = [(int(obj_ids[k % len(obj_ids)]), _pose(Rotation.random(random_state=rng).as_matrix(),
                                                           [70.0 * k - 35.0, 10.0 * k, 20.0])) for k in range(3)]  # fmt: skip
        built.objects[sid] = objects
        for k, sensor in enumerate(spec.sensors):
            order = list(range(len(objects)))
            if k == 1:
                order.reverse()
            if k == len(spec.sensors) - 1 and k > 0:
                order = order[:-1]
            built.gt_order[(sid, sensor.name)] = order
            _write_sensor(built, sid, sensor, order, n_images, masks, rng)
        for im in range(n_images):
            if scene == n_scenes and im == 0:
                continue
            counts: dict[int, int] = {}
            visib = built.visib[(sid, spec.eval_sensor, im)]
            for gt_id, i in enumerate(built.gt_order[(sid, spec.eval_sensor)]):
                counts[objects[i][0]] = counts.get(objects[i][0], 0) + (visib[gt_id] >= 0.1)
            built.targets += [{"im_id": im, "inst_count": n, "obj_id": o, "scene_id": scene}
                              for o, n in sorted(counts.items()) if n]  # fmt: skip
    save_json(root / "test_targets_bop19.json", built.targets)
    return built


def _write_sensor(
    built: BuiltIndustrial, sid: str, sensor: Sensor, order: list[int], n_images: int, masks: bool, rng
) -> None:
    name, (width, height) = sensor.name, sensor.image_size
    scene_dir = built.split_dir / sid
    suffix = built.spec.image_suffix
    cameras, gts, infos = {}, {}, {}
    for im in range(n_images):
        T_cw = _look_at(rng)
        R, t = round_like_tless(T_cw)
        T_cw = _pose(np.reshape(R, (3, 3)), t)
        f = 1.2 * width
        K = np.array([[f, 0.0, width / 2 + 0.25], [0.0, f, height / 2 - 0.25], [0.0, 0.0, 1.0]])
        cameras[im] = {"cam_K": K.ravel().tolist(), "cam_R_w2c": R, "cam_t_w2c": t, "depth_scale": DEPTH_SCALE}
        built.T_cam_world[(sid, name, im)], built.K[(sid, name, im)] = T_cw, K
        gts[im] = []
        for i in order:
            obj_id, T_wm = built.objects[sid][i]
            R_m, t_m = round_like_tless(T_cw @ T_wm)
            gts[im].append({"cam_R_m2c": R_m, "cam_t_m2c": t_m, "obj_id": obj_id})
        visib = [round(float(v), 4) for v in rng.uniform(0.0, 1.0, len(order))]
        built.visib[(sid, name, im)] = visib
        infos[im] = [{"bbox_obj": [0, 0, 2, 2], "bbox_visib": [0, 0, 2, 2], "px_count_all": 4, "px_count_valid": 4,
                      "px_count_visib": math.floor(4 * v), "visib_fract": v} for v in visib]  # fmt: skip
        for modality in sensor.modalities:
            folder = scene_dir / f"{modality}_{name}"
            if modality == "depth":
                save_depth(folder / f"{im:06d}.png", np.full((height, width), 700.0), DEPTH_SCALE)
            else:
                shape = (height, width, 3) if modality == "rgb" else (height, width)
                write_image(folder / f"{im:06d}{suffix}", np.full(shape, 40 + im, np.uint8))
        if masks:
            for gt_id in range(len(order)):
                for kind in ("mask", "mask_visib"):
                    write_image(
                        scene_dir / f"{kind}_{name}" / f"{im:06d}_{gt_id:06d}.png", np.zeros((height, width), np.uint8)
                    )
    save_json(scene_dir / f"scene_camera_{name}.json", cameras)
    save_json(scene_dir / f"scene_gt_{name}.json", gts)
    save_json(scene_dir / f"scene_gt_info_{name}.json", infos)
