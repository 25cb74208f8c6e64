"""The shipped unit, installed by the documented command into a staging root, verifies.

``scripts/install-service`` with DESTDIR stages the venv (``--no-deps``: the unit only
needs the entry point to exist), the /usr/local/bin link, the unit, the rule, the
config and the docs; ``systemd-analyze verify --root`` checks the unit against that
root (ExecStart executable, directives known) and ``systemd-analyze security`` rates
its sandbox. Skipped where systemd-analyze is absent; the udev rule likewise with
``udevadm verify`` (systemd 254 and later).
"""

from __future__ import annotations

import itertools
import re
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
UNIT = REPO / "systemd" / "scotti-daemon.service"
ANALYZE = shutil.which("systemd-analyze")
needs_analyze = pytest.mark.skipif(ANALYZE is None, reason="systemd-analyze not installed")


def _with_system_units(root: Path) -> None:
    """The host's unit files inside ``root``: the targets the unit is ordered against."""
    (root / "usr/lib/systemd").mkdir(parents=True, exist_ok=True)
    shutil.copytree("/usr/lib/systemd/system", root / "usr/lib/systemd/system", symlinks=True)


def analyze(*args: str) -> subprocess.CompletedProcess[str]:
    assert ANALYZE is not None
    return subprocess.run([ANALYZE, *args], capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if ANALYZE is None:
        pytest.skip("systemd-analyze not installed")
    root = tmp_path_factory.mktemp("root")
    env = {"DESTDIR": str(root), "SCOTTI_PIP_ARGS": "--no-deps", "PATH": "/usr/bin:/bin"}
    out = subprocess.run(
        [str(REPO / "scripts" / "install-service")],
        capture_output=True,
        text=True,
        timeout=600,
        env={**env, "HOME": str(root)},
    )
    assert out.returncode == 0, out.stderr
    _with_system_units(root)
    return root


@needs_analyze
@pytest.mark.slow
def test_the_install_puts_everything_where_the_unit_expects_it(installed: Path) -> None:
    unit = installed / "etc/systemd/system/scotti-daemon.service"
    assert unit.read_bytes() == UNIT.read_bytes()  # the shipped unit, unchanged
    exec_start = re.search(r"^ExecStart=(\S+)", unit.read_text(), re.M)
    assert exec_start is not None
    link = installed / exec_start.group(1).lstrip("/")
    assert link.is_symlink()
    assert (installed / str(link.readlink()).lstrip("/")).is_file()  # the venv's entry point
    for doc in re.findall(r"file://(\S+)", unit.read_text().split("[Service]")[0]):
        assert (installed / doc.lstrip("/")).is_file(), doc  # Documentation= is installed
    assert (installed / "etc/scotti/scotti-daemon.toml").is_file()
    assert (installed / "etc/udev/rules.d/99-scotti-receiver.rules").is_file()


@needs_analyze
@pytest.mark.slow
def test_systemd_analyze_verify_passes(installed: Path) -> None:
    out = analyze("verify", f"--root={installed}", "scotti-daemon.service")
    assert out.returncode == 0, out.stderr
    assert "scotti-daemon" not in out.stderr, out.stderr


@needs_analyze
def test_verify_fails_without_the_install(tmp_path: Path) -> None:
    """The check can fail: the unit alone, with no /usr/local/bin/scotti-daemon."""
    (tmp_path / "etc/systemd/system").mkdir(parents=True)
    shutil.copy(UNIT, tmp_path / "etc/systemd/system")
    _with_system_units(tmp_path)
    out = analyze("verify", f"--root={tmp_path}", "scotti-daemon.service")
    assert out.returncode != 0
    assert "/usr/local/bin/scotti-daemon is not executable" in out.stderr


@needs_analyze
@pytest.mark.slow
def test_security_exposure_stays_at_2_or_better(installed: Path) -> None:
    out = analyze(
        "security", "--offline=true", f"--root={installed}", "--threshold=20", "--no-pager",
        "scotti-daemon.service",
    )  # fmt: skip
    assert out.returncode == 0, out.stdout + out.stderr
    level = re.search(r"Overall exposure level for scotti-daemon.service: ([\d.]+)", out.stdout)
    assert level is not None, out.stdout
    assert float(level.group(1)) <= 2.0


def test_udev_rule_verifies() -> None:
    udevadm = shutil.which("udevadm")
    if udevadm is None:
        pytest.skip("udevadm not installed")
    probe = subprocess.run([udevadm, "verify", "--help"], capture_output=True, check=False)
    if probe.returncode != 0:
        pytest.skip("udevadm has no 'verify' (systemd < 254)")
    rule = REPO / "systemd" / "99-scotti-receiver.rules"
    out = subprocess.run([udevadm, "verify", str(rule)], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


DEPLOY = REPO / "docs" / "deploy.md"
LIMITS = ("LimitNOFILE", "MemoryMax", "TasksMax")
_SIZE = {"K": 2**10, "M": 2**20, "G": 2**30}


def _unit_value(key: str) -> str:
    found = re.findall(rf"^{key}=(\S+)$", UNIT.read_text(), re.M)
    assert len(found) == 1, f"{key}= set {len(found)} times in the unit"
    return str(found[0])


def _bytes(value: str) -> int:
    return int(value[:-1]) * _SIZE[value[-1]] if value[-1] in _SIZE else int(value)


def _table(heading: str) -> list[list[str]]:
    """The body rows of the first Markdown table from the line that holds ``heading``."""
    text = DEPLOY.read_text()
    lines = text[text.index(heading) :].splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("|"))
    block = list(itertools.takewhile(lambda line: line.startswith("|"), lines[start:]))
    return [[c.strip() for c in line.strip("|").split("|")] for line in block[2:]]


def test_the_unit_bounds_descriptors_memory_and_tasks_as_the_docs_say() -> None:
    stated = {row[0].strip("`"): row[1] for row in _table("## The unit's limits")}
    assert set(stated) == set(LIMITS)
    for key in LIMITS:
        assert _unit_value(key) == stated[key], key  # the docs give the unit's values


def test_the_limits_leave_room_over_the_measured_peaks() -> None:
    """Twice the largest peak the benchmark measured (the docs' table) at least."""
    peaks = _table("| pairs | processes | on |")
    assert [row[0] for row in peaks].count("32") == 4, peaks
    rss_mib = max(float(row[3]) for row in peaks)
    threads = max(int(row[4]) for row in peaks)
    fds = max(int(row[5]) for row in peaks)
    assert _bytes(_unit_value("MemoryMax")) >= 2 * rss_mib * 2**20
    assert int(_unit_value("TasksMax")) >= 2 * threads
    assert int(_unit_value("LimitNOFILE")) >= 2 * fds


@needs_analyze
def test_the_unit_file_rates_2_or_better_as_it_stands() -> None:
    """The sandbox's rating of the unit file itself (no install needed): the resource
    keys must not cost any of it."""
    out = analyze("security", "--offline=true", "--no-pager", str(UNIT))
    level = re.search(r"Overall exposure level for scotti-daemon.service: ([\d.]+)", out.stdout)
    assert level is not None, out.stdout + out.stderr
    assert float(level.group(1)) <= 2.0
