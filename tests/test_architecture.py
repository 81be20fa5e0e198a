"""The layout's rules (``docs/architecture.md``): data flows one way through the stages' packages, the command line
only parses and prints, and no module grows past what one job needs."""

from __future__ import annotations

import ast
from pathlib import Path

import spotnav
from spotnav.errors import SpotnavError

PACKAGE = Path(spotnav.__file__).parent
# Each stage imports only from the stages before it.
STAGES = ("errors", "setup", "optics", "image", "pose", "files", "app", "experiments", "arguments", "cli")


def _stage(module: str) -> str:
    return module.removeprefix("spotnav.").split(".")[0]


def _spotnav_imports(path: Path) -> list[str]:
    tree = ast.parse(path.read_text())
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("spotnav."):
            found.append(node.module or "")
        elif isinstance(node, ast.Import):
            found.extend(alias.name for alias in node.names if alias.name.startswith("spotnav."))
    return found


def _modules() -> list[Path]:
    return [path for path in sorted(PACKAGE.rglob("*.py")) if path.parent != PACKAGE or path.stem in STAGES]


def test_data_flows_one_way_through_the_stages() -> None:
    backwards = []
    for path in _modules():
        own = STAGES.index(_stage(".".join(path.relative_to(PACKAGE).with_suffix("").parts)))
        for module in _spotnav_imports(path):
            if STAGES.index(_stage(module)) > own:
                backwards.append(f"{path.relative_to(PACKAGE)} imports {module}")
    assert backwards == []


def test_modules_stay_small_and_the_command_line_thin() -> None:
    lines = {path.relative_to(PACKAGE): len(path.read_text().splitlines()) for path in PACKAGE.rglob("*.py")}
    assert {path: n for path, n in lines.items() if n > 700} == {}
    assert lines[Path("cli.py")] <= 400


# Pillow's plugins raise a plain ValueError for a header they cannot parse (PNG's "Truncated IHDR chunk"), with no
# narrower class: the one handler of a ValueError, around Pillow's call alone, where OpenCV is left to decide.
AROUND_A_LIBRARY = {("files/images.py", "image_size")}


def test_a_user_error_is_not_a_value_error_and_no_value_error_of_ours_is_caught() -> None:
    assert not issubclass(SpotnavError, ValueError)
    catching = set()
    for path in PACKAGE.rglob("*.py"):
        for function in ast.walk(ast.parse(path.read_text())):
            if not isinstance(function, ast.FunctionDef):
                continue
            for node in ast.walk(function):
                if isinstance(node, ast.ExceptHandler) and node.type is not None:
                    names = node.type.elts if isinstance(node.type, ast.Tuple) else [node.type]
                    if any(isinstance(name, ast.Name) and name.id == "ValueError" for name in names):
                        catching.add((str(path.relative_to(PACKAGE)), function.name))
    assert catching == AROUND_A_LIBRARY
