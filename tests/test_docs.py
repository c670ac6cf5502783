"""The reference pages checked against the code: docs/architecture.md names every module of the package
and no module that is gone; docs/configuration.md names every field of the run's configuration types.
No JAX: the configuration types are read from their source."""

import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# The repository's folders of the installed package, with the prefix architecture.md gives their files.
PACKAGE_FOLDERS = {"mjx_push": "mjx_push", "train": "train", "export": "export"}


def _modules(folder: str) -> set[str]:
    """The package's modules in `folder`, as paths under it (`runs/checkpoints.py`), without __init__."""
    root = REPO / folder
    return {p.relative_to(root).as_posix() for p in root.rglob("*.py") if p.name not in ("__init__.py", "__main__.py")}


def _named_in(text: str) -> set[str]:
    return set(re.findall(r"`([\w/]+\.py)`", text))


def test_architecture_names_every_module_and_no_missing_one():
    text = (REPO / "docs" / "architecture.md").read_text()
    named = _named_in(text)
    missing = {f"{folder}/{m}" for folder in PACKAGE_FOLDERS for m in _modules(folder) if m not in named}
    assert not missing, f"docs/architecture.md does not name: {sorted(missing)}"
    every = {p.relative_to(REPO).as_posix() for p in REPO.rglob("*.py") if ".venv" not in p.parts}
    gone = {n for n in named if not any(path == n or path.endswith("/" + n) for path in every)}
    assert not gone, f"docs/architecture.md names modules that do not exist: {sorted(gone)}"


def _dataclass_fields(path: Path) -> dict[str, list[str]]:
    """{class name: its annotated fields} for every class of a source file."""
    tree = ast.parse(path.read_text())
    out = {}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            out[node.name] = [
                n.target.id
                for n in node.body
                if isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name) and not n.target.id.startswith("_")
            ]
    return out


# The configuration types a run's config.json holds, by the file that defines them.
CONFIG_TYPES = {
    "train/config.py": (
        "AgentConfig",
        "SACConfig",
        "ReplayConfig",
        "LoopConfig",
        "DemoConfig",
        "TrainConfig",
        "RunConfig",
    ),
    "mjx_push/config.py": ("ObjectConfig", "ControllerConfig", "EnvConfig"),
    "mjx_push/scene.py": ("SolverSettings",),
    "mjx_push/expert.py": ("ExpertConfig",),
}


def test_configuration_names_every_field():
    text = (REPO / "docs" / "configuration.md").read_text()
    named = set(re.findall(r"`([\w.]+)`", text))
    named |= {part for name in named for part in name.split(".")}
    missing = []
    for file, classes in CONFIG_TYPES.items():
        fields = _dataclass_fields(REPO / file)
        for cls in classes:
            assert cls in fields, f"{file} has no class {cls} (update CONFIG_TYPES)"
            missing += [f"{cls}.{f}" for f in fields[cls] if f not in named]
    assert not missing, f"docs/configuration.md does not name: {missing}"


def test_the_checks_fail_on_a_page_that_drifted(tmp_path):
    """What the two checks read: a page without a module's name, or with a field left out, is caught."""
    assert "runs/checkpoints.py" in _modules("train")
    assert "runs/checkpoints.py" not in _named_in("`checkpoints.py` (orbax)")
    fields = _dataclass_fields(REPO / "train" / "config.py")
    assert "lr" in fields["SACConfig"] and "her_k" in fields["ReplayConfig"]


def test_every_page_is_linked_from_the_readme_and_within_its_size():
    readme = (REPO / "README.md").read_text()
    pages = sorted(p for p in (REPO / "docs").glob("*.md"))
    unlinked = [p.name for p in pages if f"docs/{p.name}" not in readme]
    assert not unlinked, f"README.md links no: {unlinked}"
    large = {p.name: p.stat().st_size for p in pages if p.stat().st_size > 15_000}
    assert not large, f"pages over 15 KB (split them): {large}"
    assert len(readme.encode()) <= 10_500, "README.md is the user's door: about 10 KB"
