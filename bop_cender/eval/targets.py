"""BOP'19 test targets: which (image, object) pairs are evaluated, and how many instances of each.

Three sources, in this order (:func:`resolve_targets`):

1. ``test_targets_bop19.json`` at the dataset root (BOP datasets, T-LESS), as the loader read it
   (:meth:`~bop_cender.data.types.Dataset.bop19_targets`), cut to the images of the split the scorer loaded.
2. No file, but every GT instance has a ``visib_fract`` (``scene_gt_info.json``): the rule of the
   toolkit's ``scripts/enumerate_test_targets.py``: per image and object, ``inst_count`` = number of
   instances with ``visib_fract >= 0.1``; the pair is a target when that count is positive.
3. No visibility either (DIMO): the same rule on visible fractions rendered for the whole pile
   (:mod:`bop_cender.eval.visibility`), carriers included as occluders, target objects only.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from bop_cender.data.layout import MIN_VISIB_FRACT, TARGETS_FILE
from bop_cender.data.targets_file import Target
from bop_cender.data.types import Dataset, Scene
from bop_cender.errors import DatasetError
from bop_cender.eval.ground_truth import GroundTruth, ImageGt, collect_ground_truth

SOURCE_FILE = "file"
SOURCE_GT_INFO = "scene_gt_info"
SOURCE_RENDERED = "rendered"

#: ``(scene_int, im_id) -> {gt_id: visib_fract}`` for every image of a GroundTruth.
VisibFracts = dict[tuple[int, int], dict[int, float]]


@dataclass(frozen=True)
class TargetSet:
    """The evaluation targets and where they came from.

    Attributes:
        targets: one per (scene, image, object), scene ids as BOP ints.
        source: :data:`SOURCE_FILE`, :data:`SOURCE_GT_INFO` or :data:`SOURCE_RENDERED`.
        note: one human-readable line for the report.
        visib: visible fractions of every instance (``scene_gt_info``, else rendered): the targets' rule
            uses them, and the valid GTs of an image are its most visible instances.
    """

    targets: list[Target]
    source: str
    note: str
    visib: VisibFracts


def resolve_targets(
    file_targets: list[Target] | None,
    gt: GroundTruth,
    target_obj_ids: Iterable[int],
    render_visib: Callable[[], VisibFracts],
    targets_path: Path | None = None,
) -> TargetSet:
    """Targets of the loaded images: from the targets file, else by the visibility rule (see module doc).

    Args:
        file_targets: the dataset's ``test_targets_bop19.json`` (:meth:`Dataset.bop19_targets`), None without one.
        gt: the loaded images.
        target_obj_ids: objects that can be targets (DIMO carriers are not).
        render_visib: computes rendered visible fractions; called only when nothing else is available.
        targets_path: the file ``file_targets`` came from (named in errors).

    Raises:
        DatasetError: a file target asks for more instances than its image's ground truth has.
    """
    targetable = set(target_obj_ids)
    stored = stored_visib(gt)
    if file_targets is not None:
        targets = [t for t in file_targets if (t.scene_id, t.im_id) in gt.images]
        check_against_ground_truth(targets, gt, targets_path)
        visib = stored if stored is not None else render_visib()  # valid GTs are the most visible ones
        return TargetSet(targets, SOURCE_FILE, f"targets from {TARGETS_FILE}: {_count(targets)}", visib)
    if stored is not None:
        targets = targets_from_visibility(gt, stored, targetable)
        note = f"no {TARGETS_FILE}: targets by the toolkit's rule visib_fract >= {MIN_VISIB_FRACT} on scene_gt_info"
        return TargetSet(targets, SOURCE_GT_INFO, f"{note}: {_count(targets)}", stored)
    visib = render_visib()
    targets = targets_from_visibility(gt, visib, targetable)
    note = (
        f"no {TARGETS_FILE} and no scene_gt_info: targets by the rule visib_fract >= {MIN_VISIB_FRACT} on"
        " visible fractions rendered for the whole pile (carriers as occluders; visible pixels / pixels of"
        f" the object rendered alone): {_count(targets)}"
    )
    return TargetSet(targets, SOURCE_RENDERED, note, visib)


def check_against_ground_truth(targets: list[Target], gt: GroundTruth, path: Path | None) -> None:
    """Refuse a target whose ``inst_count`` exceeds its object's GT instances in the image (the toolkit's rule
    counts the instances with visib_fract >= 0.1, never more): the file is not this dataset's, or damaged, and
    the top-``inst_count`` cut would keep estimates that no instance can match.

    Raises:
        DatasetError: naming the file and the (first such) target.
    """
    problems = inst_count_problems(targets, gt, path)
    if problems:
        raise problems[0]


def inst_count_problems(targets: Iterable[Target], gt: GroundTruth, path: Path | None) -> list[DatasetError]:
    """One error per target of a loaded image whose ``inst_count`` exceeds the image's GT instances of its
    object (see :func:`check_against_ground_truth`; ``bop-cender info`` lists them all). Targets of images
    not in ``gt`` are not judged."""
    problems = []
    for t in targets:
        image = gt.images.get((int(t.scene_id), t.im_id))
        if image is None:
            continue
        n = sum(g.obj_id == t.obj_id for g in image.instances)
        if t.inst_count > n:
            problems.append(
                DatasetError(
                    f"the target of scene {t.scene_id}, image {t.im_id}, object {t.obj_id} has inst_count"
                    f" {t.inst_count}, but the image's ground truth has {n} instance(s) of that object",
                    file=path if path is not None else TARGETS_FILE,
                    field="inst_count",
                )
            )
    return problems


def stored_visib(gt: GroundTruth) -> VisibFracts | None:
    """``visib_fract`` of every instance from ``scene_gt_info.json``; None if any instance lacks one."""
    out: VisibFracts = {}
    for image in gt:
        fracts = {g.gt_id: g.visib_fract for g in image.instances}
        if any(v is None for v in fracts.values()):
            return None
        out[image.key] = fracts  # type: ignore[assignment]
    return out


def targets_from_visibility(
    images: Iterable[ImageGt], visib: Mapping[tuple[int, int], Mapping[int, float]], target_obj_ids: set[int]
) -> list[Target]:
    """The ``enumerate_test_targets.py`` rule: per image, objects with instances of ``visib_fract >= 0.1``.

    Images in the given order; objects in order of their first such instance (gt_id order), as the toolkit
    writes them.
    """
    targets = []
    for image in images:
        fracts = visib.get(image.key, {})
        counts: dict[int, int] = {}
        for g in image.instances:
            if g.obj_id in target_obj_ids and fracts.get(g.gt_id, 0.0) >= MIN_VISIB_FRACT:
                counts[g.obj_id] = counts.get(g.obj_id, 0) + 1
        targets.extend(Target(image.scene_int, image.im_id, obj_id, n) for obj_id, n in counts.items())
    return targets


def _count(targets: list[Target]) -> str:
    images = len({(t.scene_id, t.im_id) for t in targets})
    return f"{len(targets)} targets, {sum(t.inst_count for t in targets)} instances in {images} images"


def targets_file_problems(dataset: Dataset, scenes: Sequence[Scene]) -> list[str]:
    """What ``score`` would refuse in the dataset's ``test_targets_bop19.json`` for the loaded ``scenes``, one
    formatted line each (``bop-cender info`` lists them; none without a targets file): a malformed file, or
    targets asking for more instances than their image's ground truth has."""
    try:
        targets = dataset.bop19_targets()
        if targets is None:
            return []
        gt = collect_ground_truth(dataset, progress=False, scenes=scenes)
    except DatasetError as e:
        return [e.format()]
    return [e.format() for e in inst_count_problems(targets, gt, dataset.root / TARGETS_FILE)]
