"""The BOP-Industrial datasets' constants (IPD, XYZ-IBD, ITODD-MV) as one table.

Facts from ``bop_toolkit_lib/dataset_params.py`` (thodan/bop_toolkit @ cea62d6): ``get_model_params`` (object ids,
symmetric object ids), ``get_split_params`` (per sensor its modalities ``im_modalities``, its image size ``im_size``,
the file suffixes ``exts``, the evaluated ``eval_sensor`` / ``eval_modality``) and ``scripts/eval_bop24_pose.py``
(``max_num_estimates_per_image``: 200 for ``xyzibd``, else 100). Only the facts are reused, none of the code.

Where the toolkit's values differ per split type: its ``pbr`` splits of XYZ-IBD and ITODD-MV are in the classic
single-sensor layout (``eval_sensor`` None), which the generic BOP loader reads; this table describes the
multi-sensor splits (``test``, ``val``, real ``train``).
"""

from __future__ import annotations

from dataclasses import dataclass

from bop_cender.data.types import Sensor


@dataclass(frozen=True)
class IndustrialSpec:
    """One multi-sensor dataset's constants.

    Attributes:
        name: dataset name as BOP writes it (``ipd``).
        sensors: every sensor, the evaluated one first, then in the toolkit's order.
        eval_modality: the evaluated sensor's modality (``rgb`` for IPD's Photoneo, ``gray`` elsewhere).
        obj_ids: the dataset's object ids (IPD starts at 0).
        symmetric_obj_ids: the objects the toolkit lists as symmetric; None: no list, ``models_info.json`` alone
            says (a synthetic catalogue).
        image_suffix: suffix of every image file (``.png``; ITODD-MV ``.tif``).
        max_estimates_per_image: the BOP'24 cap of estimates per image.
    """

    name: str
    sensors: tuple[Sensor, ...]
    eval_modality: str
    obj_ids: tuple[int, ...]
    symmetric_obj_ids: tuple[int, ...] | None
    image_suffix: str = ".png"
    max_estimates_per_image: int = 100

    @property
    def eval_sensor(self) -> str:
        """The sensor whose images BOP evaluates (results rows are in its camera frame)."""
        return self.sensors[0].name

    def sensor(self, name: str) -> Sensor:
        return next(s for s in self.sensors if s.name == name)


def _polarised(name: str) -> Sensor:
    """An IPD FLIR camera: RGB, angle and degree of linear polarisation, depth; 3840x2160."""
    return Sensor(name, ("rgb", "aolp", "dolp", "depth"), (3840, 2160))


#: Name -> constants (``dataset_params.py``, thodan/bop_toolkit @ cea62d6).
INDUSTRIAL: dict[str, IndustrialSpec] = {
    "ipd": IndustrialSpec(
        name="ipd",
        sensors=(Sensor("photoneo", ("rgb", "depth"), (2064, 1544)), _polarised("cam1"), _polarised("cam2"),
                 _polarised("cam3")),
        eval_modality="rgb",
        obj_ids=(0, 1, 4, 8, 10, 11, 14, 18, 19, 20),
        symmetric_obj_ids=(8, 14, 18, 19, 20),
    ),
    "xyzibd": IndustrialSpec(
        name="xyzibd",
        sensors=(Sensor("xyz", ("gray", "depth"), (1440, 1080)), Sensor("photoneo", ("gray", "depth"), (2064, 1544)),
                 Sensor("realsense", ("rgb", "depth"), (1280, 720))),
        eval_modality="gray",
        obj_ids=(1, 2, 4, 5, 6, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17),
        symmetric_obj_ids=(1, 2, 5, 8, 9, 11, 12, 16, 17),
        max_estimates_per_image=200,
    ),
    "itoddmv": IndustrialSpec(
        name="itoddmv",
        sensors=(Sensor("3dlong", ("gray", "depth"), (1280, 960)), Sensor("cam0", ("gray",), (4224, 2838)),
                 Sensor("cam1", ("gray",), (4224, 2838)), Sensor("cam2", ("gray",), (4224, 2838))),
        eval_modality="gray",
        obj_ids=tuple(range(1, 29)),
        symmetric_obj_ids=(2, 3, 4, 5, 7, 8, 9, 11, 12, 14, 17, 18, 19, 23, 24, 25, 27, 28),
        image_suffix=".tif",
    ),
}  # fmt: skip


#: The sets ``bop-cender synth --layout industrial`` writes (:mod:`bop_cender.synth.write_industrial`): a bin of
#: DIMO parts (ids 1..6) seen by a gray evaluated camera, two RGB cameras and a gray camera with depth. Not a BOP
#: name: the reader takes it for a folder whose generator record says ``"layout": "industrial"``
#: (:func:`bop_cender.data.industrial.synth_spec`).
SYNTH_INDUSTRIAL = IndustrialSpec(
    name="synth_industrial",
    sensors=(Sensor("hires", ("gray",), (320, 256)), Sensor("left", ("rgb",), (256, 192)),
             Sensor("right", ("rgb",), (256, 192)), Sensor("tof", ("gray", "depth"), (240, 180))),
    eval_modality="gray",
    obj_ids=(1, 2, 3, 4, 5, 6),
    symmetric_obj_ids=None,
)  # fmt: skip
