"""Packaging (pyproject.toml): the pins equal requirements*.txt's, and `pip install .` gives a
package that carries the shipped scenes and the `taichi-cloth` command, which runs from any
folder and lists every scene (the hard cases and the lab's specimens too)."""

import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def pins(path: Path) -> list[str]:
    """The ``name==version`` lines of a requirements file, comments dropped."""
    lines = (line.split("#")[0].strip() for line in path.read_text().splitlines())
    return [line for line in lines if line]


def test_pyproject_pins_are_the_requirements_files():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["dependencies"] == pins(ROOT / "requirements.txt")
    assert project["optional-dependencies"]["test"] == pins(ROOT / "requirements-test.txt")
    assert all(re.fullmatch(r"[A-Za-z0-9_.-]+==[0-9][0-9A-Za-z.]*", pin)
               for pin in pins(ROOT / "requirements.txt") + pins(ROOT / "requirements-test.txt"))
    assert project["scripts"] == {"taichi-cloth": "taichi_cloth.cli:main"}


def test_pip_install_carries_the_scenes_and_the_command(tmp_path):
    """The sources copied alone (pyproject, README, the package with its link to scenes/),
    installed with pip into a folder of their own; the command, run elsewhere with that folder
    on the path, finds every shipped scene inside the installed package."""
    source = tmp_path / "source"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    shutil.copytree(ROOT / "taichi_cloth", source / "taichi_cloth", symlinks=True,
                    ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(ROOT / "scenes", source / "scenes")
    target = tmp_path / "installed"
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps",
                    "--target", str(target), str(source)], check=True, capture_output=True)
    installed_scenes = target / "taichi_cloth" / "scenes"
    shipped = sorted(p.relative_to(ROOT / "scenes") for p in (ROOT / "scenes").rglob("*")
                     if p.is_file())
    assert sorted(p.relative_to(installed_scenes) for p in installed_scenes.rglob("*")
                  if p.is_file()) == shipped
    assert not installed_scenes.is_symlink()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    result = subprocess.run([str(target / "bin" / "taichi-cloth"), "scenes"], cwd=elsewhere,
                            capture_output=True, text=True,
                            env={**os.environ, "PYTHONPATH": str(target)})
    assert result.returncode == 0, result.stderr
    names = [line.split()[0] for line in result.stdout.splitlines() if line.strip()]
    assert sorted(names) == sorted(p.relative_to(ROOT / "scenes").with_suffix("").as_posix()
                                   for p in (ROOT / "scenes").rglob("*.toml"))
    usage = subprocess.run([str(target / "bin" / "taichi-cloth"), "--help"], cwd=elsewhere,
                           capture_output=True, text=True,
                           env={**os.environ, "PYTHONPATH": str(target)})
    assert usage.stdout.startswith("usage: taichi-cloth")
