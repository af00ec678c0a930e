"""``bop-cender convert-pvnet``: PVNet-style poses -> a BOP results CSV."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``convert-pvnet`` to ``bop-cender``'s subparsers."""
    p = sub.add_parser("convert-pvnet", help="PVNet-style 3x4 poses (t in metres) -> BOP results CSV (mm)")
    p.add_argument("input", type=Path, help="folder of {scene}_{im}_{obj}.npy / {scene}/{im}_{obj}.npy, or a JSON file")
    p.add_argument("--out", type=Path, required=True, help="output CSV, a BOP name such as pvnet_tless-test.csv")
    p.add_argument("--dataset-root", type=Path, default=None, help="check object ids against this dataset's models")
    p.set_defaults(func=cmd_convert_pvnet)


def cmd_convert_pvnet(args: argparse.Namespace) -> int:
    from bop_cender.data.bop_io import check_output_file
    from bop_cender.results.convert_pvnet import convert_pvnet

    check_output_file(args.out)
    known = None
    if args.dataset_root is not None:
        known = _model_ids(args.dataset_root)
    rows = convert_pvnet(args.input, args.out, known_obj_ids=known)
    print(f"wrote {len(rows)} estimates to {args.out}")
    return 0


def _model_ids(root: Path) -> list[int]:
    """Object ids of a dataset's evaluation models (``models_eval/``, else ``models/`` or ``models_cad/``)."""
    from bop_cender.data.bop_io import as_int, load_json
    from bop_cender.errors import DatasetError

    for name in ("models_eval", "models", "models_cad"):
        path = root / name / "models_info.json"
        if path.is_file():
            return sorted(as_int(k, path, repr(k), strings=True) for k in load_json(path))
    raise DatasetError("no models_eval/, models/ or models_cad/ with a models_info.json", file=root)
