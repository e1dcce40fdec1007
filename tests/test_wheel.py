"""The package as users install it: a wheel and an sdist built from the working tree hold every module, the
shipped weights and the sample; the wheel, installed without `-e` into its own environment, runs the main
commands from that install alone (nothing from the repository on the path)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import zipfile
from pathlib import Path
from typing import Final

import numpy as np
import pytest

from aftershock.pipeline.cloud_io import write_cloud
from aftershock.pipeline.types import LabelledCloud

REPO: Final = Path(__file__).resolve().parents[1]
PACKAGE_FOLDERS: Final = {"pipeline": "pipeline", "sources": "sources", "sinks": "sinks", "models": "models"}
SHIPPED: Final = (
    "aftershock/recordings/sample.mcap",
    "aftershock/models/weights/mcpnet.pt",
    "aftershock/models/weights/scan_reference.json",  # the distribution check of every run reads it
)


def _source_tree(dest: Path) -> Path:
    """A copy of the files git would commit (tracked and new, not ignored): the wheel is built as from a clean
    checkout, and the build leaves nothing behind in the repository."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=REPO,
        capture_output=True,
        check=True,
    ).stdout.split(b"\0")
    for rel in filter(None, (x.decode() for x in listed)):
        src = REPO / rel
        if src.is_file() and not rel.startswith(("tests/", "docs/")):
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)
    return dest


def _expected_files() -> set[str]:
    """Every module and shipped data file, as paths inside the wheel."""
    out = set(SHIPPED)
    for folder in (*PACKAGE_FOLDERS, "recordings"):
        for path in (REPO / folder).rglob("*"):
            if path.suffix in (".py", ".pt", ".mcap") and "__pycache__" not in path.parts:
                out.add(f"aftershock/{path.relative_to(REPO).as_posix()}")
    return out


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(wheel, sdist) built from a copy of the working tree with this environment's setuptools."""
    if shutil.which("git") is None or not (REPO / ".git").exists():
        pytest.skip("needs a git checkout to know which files a clean checkout holds")
    tree = _source_tree(tmp_path_factory.mktemp("src"))
    dist = tmp_path_factory.mktemp("dist")
    subprocess.run(
        [sys.executable, "-m", "build", "--no-isolation", "--wheel", "--sdist", "--outdir", str(dist), str(tree)],
        check=True,
        capture_output=True,
    )
    return next(dist.glob("*.whl")), next(dist.glob("*.tar.gz"))


@pytest.fixture(scope="module")
def installed(built: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A new virtual environment holding the wheel (not editable); the dependencies come from this
    environment's site-packages through a .pth line, which adds the folder without running its own .pth
    files, so the editable install of the repository stays out."""
    wheel, _ = built
    env = tmp_path_factory.mktemp("venv")
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(env)], check=True)
    site = next((env / "lib").glob("python3*/site-packages"))
    (site / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    pip = [sys.executable, "-m", "pip", "--python", str(env / "bin" / "python"), "--disable-pip-version-check"]
    subprocess.run([*pip, "install", "-q", "--no-deps", "--no-index", str(wheel)], check=True, capture_output=True)
    return env


def _aftershock(env: Path, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    clean = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    return subprocess.run(
        [str(env / "bin" / "aftershock"), *args],
        cwd=cwd,
        env=dict(clean, CI="true", RERUN_ANALYTICS="0"),
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_wheel_holds_every_module_and_the_shipped_data(built: tuple[Path, Path]) -> None:
    wheel, _ = built
    names = set(zipfile.ZipFile(wheel).namelist())
    missing = _expected_files() - names
    assert not missing, sorted(missing)
    tops = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert tops == {"aftershock"}, f"the wheel installs more than the aftershock namespace: {tops}"
    entry_points = next(n for n in names if n.endswith(".dist-info/entry_points.txt"))
    assert "aftershock = aftershock.pipeline.__main__:entry" in zipfile.ZipFile(wheel).read(entry_points).decode()


def test_sdist_holds_every_module_and_the_shipped_data(built: tuple[Path, Path]) -> None:
    _, sdist = built
    with tarfile.open(sdist) as tar:
        names = {n.split("/", 1)[1] for n in tar.getnames() if "/" in n}
    expected = {f.removeprefix("aftershock/") for f in _expected_files()}
    missing = expected - names
    assert not missing, sorted(missing)
    assert {"pyproject.toml", "README.md"} <= names


def test_installed_wheel_runs_the_main_commands(installed: Path, tmp_path: Path) -> None:
    """`info`, `run` on the bundled sample, `refine` on its map, `cracks` and `drift` on small clouds, all
    from the installed copy (checked: the modules load from the new environment, not from the repository)."""
    where = subprocess.run(
        [str(installed / "bin" / "python"), "-c", "import aftershock.pipeline.cli as c; print(c.__file__)"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    assert Path(where).is_relative_to(installed), where
    bare = subprocess.run([str(installed / "bin" / "python"), "-c", "import pipeline"], cwd=tmp_path)
    assert bare.returncode != 0, "a bare `pipeline` package is importable"

    sample = _aftershock(installed, "info", str(REPO / "recordings" / "sample.mcap"), "--json", "-q", cwd=tmp_path)
    assert sample.returncode == 0, sample.stderr
    assert json.loads(sample.stdout)

    run = _aftershock(installed, "run", "--max-scans", "3", "--export", "out", "--json", "-q", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["scans"] == 3 and summary["labeller"] == "mcpnet", summary  # shipped weights found
    assert (tmp_path / "out" / "map.ply").is_file()

    refine = _aftershock(installed, "refine", "out/map.ply", "--no-baselines", "--json", cwd=tmp_path)
    assert refine.returncode == 0, refine.stderr
    assert json.loads(refine.stdout)["segments"] > 0

    from aftershock.sources.simulator.cracks import cracked_element

    element, _, _ = cracked_element("wall", 3, 0.004)
    write_cloud(tmp_path / "wall.ply", element)
    cracks = _aftershock(installed, "cracks", "wall.ply", "--json", cwd=tmp_path)
    assert cracks.returncode == 0, cracks.stderr
    assert "cracks" in json.loads(cracks.stdout)

    rng = np.random.default_rng(0)
    slabs = [np.c_[rng.uniform(-4, 4, (20000, 2)), np.full(20000, z) + rng.normal(0, 0.002, 20000)] for z in (0, 3)]
    write_cloud(tmp_path / "frame.ply", LabelledCloud(np.vstack(slabs)))
    drift = _aftershock(installed, "drift", "frame.ply", "--json", cwd=tmp_path)
    assert drift.returncode == 0, drift.stderr
    assert len(json.loads(drift.stdout)["stories"]) >= 1
