"""``bop-cender convert-pvnet``: PVNet-style poses -> a BOP results CSV."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``convert-pvnet`` to ``bop-cender``'s subparsers."""
    p = sub.add_parser("convert-pvnet", help="PVNet-style 3x4 poses (t in metres) -> BOP results CSV (mm)")
    p.add_argument("input", type=Path, help="folder of {scene}_{im}_{obj}.npy / {scene}/{im}_{obj}.npy, or a JSON file")
    p.add_argument("--out", type=Path, required=True, help="output CSV, a BOP name such as pvnet_tless-test.csv")
    p.add_argument(
        "--data-root",
        type=Path,
        default=None,
        help="dataset root: check object ids against its models, the units of t against their diameters, and the"
        " scenes and images against the split the --out name says (where it opens there)",
    )
    p.add_argument(
        "--model-type",
        default=None,
        help="the models folder of a root with several (cad: models_cad/), for the scene and image check",
    )
    # The name this option had before every command named the dataset root --data-root; kept, announced.
    p.add_argument("--dataset-root", type=Path, default=None, dest="old_dataset_root", help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_convert_pvnet)


def cmd_convert_pvnet(args: argparse.Namespace) -> int:
    from bop_cender.data.bop_io import check_output_file
    from bop_cender.errors import ConfigError
    from bop_cender.results.convert_pvnet import convert_pvnet

    root = args.data_root
    if args.old_dataset_root is not None:
        if root is not None:
            raise ConfigError("give --data-root alone (--dataset-root is its old name)", field="--dataset-root")
        print("warning: --dataset-root is deprecated: use --data-root", file=sys.stderr)
        root = args.old_dataset_root
    check_output_file(args.out)
    known = diameters = check = None
    if args.model_type is not None and root is None:
        raise ConfigError("chooses the models folder of --data-root: give --data-root too", field="--model-type")
    if root is not None:
        diameters = _model_diameters(root)
        known = sorted(diameters)
        check = _rows_in_split(args.out, root, args.input, args.model_type)
    rows = convert_pvnet(args.input, args.out, known_obj_ids=known, diameters=diameters, check=check)
    print(f"wrote {len(rows)} estimates to {args.out}")
    return 0


def _rows_in_split(out: Path, root: Path, source: Path, model_type: str | None = None):
    """With ``--data-root``: a check that every row's scene and image are in the split the output's BOP name says
    (``pvnet_tless-test.csv``: T-LESS ``test``), as ``score`` will check them. Where that split does not open at
    the root (a models-only root, another dataset's), a warning says why and the ids are left to ``score``."""
    from bop_cender.data.registry import DatasetRequest, open_dataset
    from bop_cender.errors import BopCenderError
    from bop_cender.eval.ground_truth import collect_ground_truth
    from bop_cender.eval.score_rows import check_rows
    from bop_cender.results.files import parse_result_filename

    name = parse_result_filename(out)
    request = DatasetRequest(name.dataset, root, name.split, split_type=name.split_type, model_type=model_type)

    def check(rows) -> None:
        try:
            dataset = open_dataset(request)
            gt = collect_ground_truth(dataset, progress=False)
        except BopCenderError as error:  # a models-only root, a split whose GT is withheld, another dataset's layout
            print(f"warning: scenes and images not checked: {error.format()}", file=sys.stderr)
            return
        check_rows(rows, gt, dataset, source)  # an unknown scene or image: refused

    return check


def _model_diameters(root: Path) -> dict[int, float]:
    """Object ids of a dataset's evaluation models (``models_eval/``, else ``models/`` or ``models_cad/``) and
    their diameters (mm; 0 where ``models_info.json`` gives none)."""
    from bop_cender.data.bop_io import as_int, as_number, load_json, require_dir
    from bop_cender.errors import ConfigError, DatasetError

    require_dir(root, "dataset root folder", ConfigError, field="--data-root")
    for name in ("models_eval", "models", "models_cad"):
        path = root / name / "models_info.json"
        if path.is_file():
            info = load_json(path)
            if not isinstance(info, dict):
                raise DatasetError(f"expected an object keyed by object id, got {type(info).__name__}", file=path)
            out = {}
            for key, entry in info.items():
                obj_id = as_int(key, path, repr(key), strings=True)
                value = entry.get("diameter") if isinstance(entry, dict) else None
                diameter = 0.0 if value is None else as_number(value, path, f"{key}.diameter")
                if value is not None and diameter <= 0:
                    raise DatasetError(
                        f"expected a positive number (mm), got {value!r}", file=path, field=f"{key}.diameter"
                    )
                out[obj_id] = diameter
            return dict(sorted(out.items()))
    raise DatasetError("no models_eval/, models/ or models_cad/ with a models_info.json", file=root)
