"""The BOP toolkit's per-dataset constants that change scores: image width for MSPD and the VSD delta.

MSPD is normalised as ``error * 640 / width`` with ``width`` the TOOLKIT's image-size constant of the
dataset split (``dataset_params.get_split_params(...)["im_size"][0]``), not the actual image width;
for a dataset the toolkit does not know, the split's actual width is the only sensible choice. The VSD
delta table is hard-coded in ``eval_bop19_pose.py`` (15 mm, 5 mm for ITODD); other names have no
entry there (the toolkit fails), so they get 15 mm unless the user says otherwise.

Values from ``bop_toolkit_lib/dataset_params.py`` (thodan/bop_toolkit @ cea62d6), test splits.
"""

from __future__ import annotations

from dataclasses import dataclass

from bop_cender.data.industrial_params import INDUSTRIAL
from bop_cender.errors import ConfigError
from bop_cender.eval.vsd import VSD_DEFAULT_DELTA, vsd_delta

#: Test-split image width (px) per dataset, per split type where it has several (None = default type).
TOOLKIT_TEST_WIDTHS: dict[str, dict[str | None, int]] = {
    "lm": {None: 640},
    "lmo": {None: 640},
    "tless": {None: 720, "primesense": 720, "kinect": 720, "canon": 2560},
    "tudl": {None: 640},
    "tyol": {None: 640},
    "ruapc": {None: 640},
    "icmi": {None: 640},
    "icbin": {None: 640},
    "itodd": {None: 1280},
    "hb": {None: 640, "primesense": 640, "kinect": 1920},
    "hbs": {None: 640, "primesense": 640, "kinect": 1920},
    "ycbv": {None: 640},
    "hope": {None: 1920},
    "hopev2": {None: 1920},
    "handal": {None: 1920},
    # BOP-Industrial: the evaluated sensor's width (eval_calc_scores.py: get_im_size(eval_modality, eval_sensor))
    **{name: {None: spec.sensors[0].image_size[0]} for name, spec in INDUSTRIAL.items()},
}
#: Datasets in eval_bop19_pose.py's VSD delta table.
TOOLKIT_VSD_DATASETS = frozenset(
    {"hb", "icbin", "icmi", "itodd", "lm", "lmo", "ruapc", "tless", "tudl", "tyol", "ycbv", "hope"}
)


@dataclass(frozen=True)
class Choice:
    """A value and where it came from (for the report)."""

    value: float
    source: str


def mspd_width(dataset: str, split: str, actual_width: int) -> Choice:
    """The width MSPD is normalised with: the toolkit's constant for a test split it knows, else ``actual_width``.

    ``split`` is the split folder (``test_kinect``): its suffix is the split type the constants depend on.

    T-LESS training splits are handled by the T-LESS loader's own table (also the toolkit's values).
    """
    if dataset == "tless" and not split.startswith("test"):
        from bop_cender.data.tless import tless_split

        try:
            return Choice(tless_split(split).image_size[0], f"the toolkit's constant for tless {split}")
        except ConfigError:  # an unknown folder name: fall through to the actual width
            pass
    widths = TOOLKIT_TEST_WIDTHS.get(dataset)
    if widths is not None and split.startswith("test"):
        kind = split.split("_", 1)[1] if "_" in split else None
        if kind in widths:
            return Choice(widths[kind], f"the toolkit's constant for {dataset} {split}")
    return Choice(actual_width, "the split's image width (dataset unknown to the toolkit)")


def vsd_delta_for(dataset: str, override: float | None = None) -> Choice:
    """VSD delta (mm): ``override`` if given, else the toolkit's table, else 15 mm."""
    if override is not None:
        return Choice(float(override), "given")
    if dataset in TOOLKIT_VSD_DATASETS:
        return Choice(vsd_delta(dataset), "the toolkit's table")
    return Choice(VSD_DEFAULT_DELTA, f"not in the toolkit's table: default {VSD_DEFAULT_DELTA:g} mm (--vsd-delta)")
