"""BOP file names and constants: the one place that spells them (docs/datasets.md).

A BOP split folder holds one folder per scene, ``{scene:06d}/`` (DIMO synthetic: ``{scene:06d}_{variant:02d}/``),
each with the files below; the dataset root holds the BOP'19 targets file and the models folders.
"""

from __future__ import annotations

#: Per-image intrinsics and world-to-camera pose (DIMO: camera-to-world too).
SCENE_CAMERA = "scene_camera.json"
#: Per-image GT instances (``obj_id``, model-to-camera pose); an instance's ``gt_id`` is its index in the list.
SCENE_GT = "scene_gt.json"
#: Per-image, per-instance visibility (``visib_fract``, pixel counts, boxes).
SCENE_GT_INFO = "scene_gt_info.json"
#: BOP'19 test targets at the dataset root.
TARGETS_FILE = "test_targets_bop19.json"
#: BOP'24 test targets at the dataset root: the images of the 6D-detection task (no instance counts).
TARGETS_FILE_BOP24 = "test_targets_bop24.json"
#: Models' sizes and symmetries (in each models folder).
MODELS_INFO = "models_info.json"
#: The record ``bop-cender synth`` keeps at the root of a dataset it made (not a BOP file: real data has none); its
#: ``complete`` field is False while a generation is under way (:func:`bop_cender.data.registry.open_dataset` warns).
SYNTH_RECORD = "bop_cender_synth.json"
#: The toolkit's minimum visible fraction of a BOP'19 target instance (``enumerate_test_targets.py``).
MIN_VISIB_FRACT = 0.1

# BOP-Industrial multi-sensor layout (IPD, XYZ-IBD, ITODD-MV; docs/datasets.md): in a scene folder, per sensor,
# ``scene_camera_{sensor}.json``, ``scene_gt_{sensor}.json``, ``scene_gt_info_{sensor}.json`` and the image folders
# ``{modality}_{sensor}/`` (``gray_xyz/``, ``depth_photoneo/``, ``mask_visib_cam1/``).
#: Per-sensor camera file: its name is ``SENSOR_CAMERA_PREFIX + sensor + ".json"``.
SENSOR_CAMERA_PREFIX = "scene_camera_"
#: Image and mask modalities of the multi-sensor folders, longest prefix first (``mask_visib`` before ``mask``).
SENSOR_FOLDER_MODALITIES = ("mask_visib", "mask", "rgb", "gray", "depth", "aolp", "dolp")


def sensor_file(kind: str, sensor: str) -> str:
    """``sensor_file("scene_gt_info", "xyz")`` -> ``scene_gt_info_xyz.json``; ``kind`` one of ``scene_camera``,
    ``scene_gt``, ``scene_gt_info``."""
    return f"{kind}_{sensor}.json"


def sensor_folder(modality: str, sensor: str) -> str:
    """``sensor_folder("gray", "xyz")`` -> ``gray_xyz`` (masks: ``mask_visib_xyz``)."""
    return f"{modality}_{sensor}"
