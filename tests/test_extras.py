"""What shipped code imports is declared in pyproject.toml: in the dependencies, or in
an extra that users install (not only ``[dev]``, which is for working on scotti).

Every import in the installed folders (static, or ``importlib.import_module`` of a
literal name) is read from the source, mapped to the distribution that provides it
in this environment, and looked up in pyproject.toml.
"""

from __future__ import annotations

import ast
import re
import sys
import tomllib
from importlib import metadata
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
FOLDERS = sorted(PYPROJECT["tool"]["setuptools"]["package-dir"].values())
DEV_ONLY = "dev"
# Where an optional package is not installed here, its distribution by name
# (the others are named as they are imported: amqtt, cobs, h5py, pylsl, ...).
DISTRIBUTION_OF = {"foxglove": "foxglove-sdk"}


def distributions(module: str) -> set[str]:
    found = metadata.packages_distributions().get(module)
    return {_name(d) for d in found or [DISTRIBUTION_OF.get(module, module)]}


def _name(requirement: str) -> str:
    """A requirement's distribution name, normalised (PEP 503)."""
    name = re.match(r"[A-Za-z0-9._-]+", requirement)
    assert name is not None, requirement
    return re.sub(r"[-_.]+", "-", name.group()).lower()


def declared() -> dict[str, set[str]]:
    """Distribution -> where pyproject.toml declares it ("" for the dependencies)."""
    out: dict[str, set[str]] = {}
    for requirement in PYPROJECT["project"]["dependencies"]:
        out.setdefault(_name(requirement), set()).add("")
    for extra, requirements in PYPROJECT["project"]["optional-dependencies"].items():
        for requirement in requirements:
            out.setdefault(_name(requirement), set()).add(extra)
    return out


def imports(path: Path) -> set[str]:
    """Top-level names of the modules ``path`` imports (absolute imports only)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module.split(".")[0])
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr == "import_module"
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
        ):
            found.add(node.args[0].value.split(".")[0])
    return found - set(sys.stdlib_module_names) - {"scotti", "__future__"}


def shipped_imports() -> dict[str, set[str]]:
    """Third-party module -> the shipped files that import it."""
    out: dict[str, set[str]] = {}
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            for module in imports(path):
                out.setdefault(module, set()).add(str(path.relative_to(ROOT)))
    return out


def test_every_third_party_import_in_shipped_code_is_declared_for_users() -> None:
    wanted = declared()
    missing = []
    for module, files in sorted(shipped_imports().items()):
        dists = distributions(module)
        where = set().union(*(wanted.get(d, set()) for d in dists))
        if not where - {DEV_ONLY}:
            shown = "only in [dev]" if where else "nowhere"
            missing.append(f"{module} ({'/'.join(sorted(dists))}) {shown}: {sorted(files)}")
    assert missing == []


@pytest.mark.parametrize(
    ("module", "extra"),
    [("psutil", "bench"), ("amqtt", "demo"), ("h5py", "import"), ("foxglove", "outputs")],
)
def test_a_tools_library_is_in_the_extra_named_for_it(module: str, extra: str) -> None:
    assert any(extra in declared().get(d, set()) for d in distributions(module))
