"""The package's structure as docs/architecture.md draws it: imports between packages go one
way (no cycle), along the layers below, and no module grows past ~400 lines."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "taichi_cloth"
# each layer may import only from the layers before it (docs/architecture.md)
LAYERS = (
    ("errors",),
    ("settings", "runtime", "flags", "gather", "uploads"),
    ("effects",),
    ("config",),
    ("cloth", "body"),
    ("physics",),
    ("render",),
    ("output",),
    ("studies",),
    ("cli",),
    ("__main__",),
)
MAX_MODULE_LINES = 420


def unit_of(path: Path) -> str:
    """The package (or top-level module) a file belongs to."""
    relative = path.relative_to(PACKAGE)
    return relative.parts[0] if len(relative.parts) > 1 else relative.stem


def package_imports() -> dict[str, set[str]]:
    """unit → the other units it imports from."""
    imports = {}
    for path in PACKAGE.rglob("*.py"):
        source = unit_of(path)
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("taichi_cloth"):
                parts = node.module.split(".")
                targets = [alias.name for alias in node.names] if len(parts) == 1 else [parts[1]]
                imports.setdefault(source, set()).update(
                    target for target in targets if target not in (source, "__init__"))
    return imports


def test_imports_follow_the_layers():
    layer_of = {unit: index for index, units in enumerate(LAYERS) for unit in units}
    imports = package_imports()
    assert set(imports) <= set(layer_of)  # every unit has its layer
    upward = [(source, target) for source, targets in imports.items() for target in targets
              if layer_of[target] >= layer_of[source]]
    assert upward == []


def test_modules_stay_small():
    sizes = {str(path.relative_to(PACKAGE)): len(path.read_text(encoding="utf-8").splitlines())
             for path in PACKAGE.rglob("*.py")}
    assert {name: lines for name, lines in sizes.items() if lines > MAX_MODULE_LINES} == {}
