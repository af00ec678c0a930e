"""The public API (``from bop_cender import ...``): what ``__all__`` lists resolves, is documented in docs/api.md,
costs ``import bop_cender`` no torch, and docs/api.md's examples run."""

from __future__ import annotations

import ast
import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

import bop_cender

ROOT = Path(__file__).resolve().parents[1]
API_DOC = ROOT / "docs" / "api.md"
PUBLIC = [n for n in bop_cender.__all__ if n != "__version__"]


def python_blocks(text: str) -> list[str]:
    """The ```python blocks of a markdown text, in order."""
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def type_checking_imports() -> dict[str, str]:
    """Name -> module of the imports under ``if TYPE_CHECKING:`` in bop_cender/__init__.py."""
    tree = ast.parse((ROOT / "bop_cender" / "__init__.py").read_text())
    block = next(n for n in tree.body if isinstance(n, ast.If) and getattr(n.test, "id", None) == "TYPE_CHECKING")
    return {a.name: n.module for n in block.body if isinstance(n, ast.ImportFrom) for a in n.names}


def test_all_lists_each_name_once_and_each_resolves_to_its_module():
    assert len(set(bop_cender.__all__)) == len(bop_cender.__all__)
    assert dict(bop_cender._HOMES) == type_checking_imports()
    assert set(PUBLIC) == set(bop_cender._HOMES)
    for name in PUBLIC:
        assert getattr(bop_cender, name) is getattr(importlib.import_module(bop_cender._HOMES[name]), name), name
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        bop_cender.not_a_name  # noqa: B018


def test_a_submodule_is_still_imported_by_name():
    from bop_cender import estimates

    assert estimates.SceneEstimate is bop_cender.SceneEstimate


def test_importing_the_package_imports_no_torch():
    """Every ``bop-cender`` command imports the package first; ``score`` forks its renderer before torch is imported."""
    code = (
        "import sys, bop_cender; print(sorted(m for m in ('torch', 'numpy', 'bop_cender.method') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT).stdout
    assert out.strip() == "[]"


def test_every_public_name_has_a_line_in_the_api_doc():
    rows = dict(re.findall(r"^\| `(\w+)` \| (.+) \|$", API_DOC.read_text(), flags=re.M))
    assert sorted(rows) == sorted(PUBLIC)
    assert all(len(text) > 20 for text in rows.values())


def run_examples(cwd: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> str:
    """Execute docs/api.md's python blocks in order, in one namespace, in ``cwd``; their stdout."""
    blocks = python_blocks(API_DOC.read_text())
    assert len(blocks) == 2
    monkeypatch.chdir(cwd)
    namespace: dict = {"__name__": "__api_examples__"}
    for block in blocks:
        exec(compile(block, str(API_DOC), "exec"), namespace)
    return capsys.readouterr().out


def test_the_api_examples_run(tmp_path, monkeypatch, capsys):
    """The examples as written, on a small two-part DIMO scene standing in for the demo and with the cheap stage-3
    settings of the runner's tests: their calls and what they print are checked here, not their accuracy."""
    sys.path.insert(0, str(ROOT / "tests"))
    import method_data

    from bop_cender.method import CenDerNetConfig
    from bop_cender.synth import demo
    from tests.test_runner import CHEAP

    root = method_data.build(tmp_path / "dimo")
    monkeypatch.setattr(demo, "ensure_demo", lambda layout, **kw: root)
    for_dataset = CenDerNetConfig.for_dataset
    monkeypatch.setattr(
        CenDerNetConfig,
        "for_dataset",
        staticmethod(lambda name, preset="ours": for_dataset(name, preset).with_settings(CHEAP)),
    )
    work = tmp_path / "work"
    work.mkdir()
    out = run_examples(work, monkeypatch, capsys)
    placed = re.findall(r"^object (\d+): score ([\d.]+), centre of its frame at", out, flags=re.M)
    assert {int(obj_id) for obj_id, _ in placed} == {3, 4}  # the scene's two parts, found by the oracle's centres
    assert f"{2 * 4} rows; the first: object" in out  # 2 objects in 4 views
    assert re.search(r"^AR_MSSD\s+\d\.\d{3}$", out, flags=re.M) and re.search(r"^AR\s+n/a$", out, flags=re.M)
    assert (work / "scores_cendernet-oracle_dimo-real.json").is_file()


@pytest.mark.slow
def test_the_api_examples_run_on_the_demo(tmp_path, monkeypatch, capsys):
    """As written, on the demo (generated into $BOP_CENDER_CACHE first where it is not there): minutes on 2 cores."""
    out = run_examples(tmp_path, monkeypatch, capsys)
    assert re.search(r"^object \d+: score", out, flags=re.M)
    assert re.search(r"^AR_MSSD\s+\d\.\d{3}$", out, flags=re.M)
