"""The built wheel works away from the repository: it carries the stage and the presets, and its env and trainer run
from a folder outside the checkout in a fresh venv that already has the dependencies; CI runs the README's test
command."""

import importlib.metadata
import json
import os
import shutil
import site
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from conftest import VIDEO_EXTRA, optional_module
from packaging.requirements import Requirement


@pytest.mark.slow
def test_wheel_runs_make_env_and_training_outside_the_repo(repo, tmp_path):
    source = shutil.copytree(repo, tmp_path / "source", ignore=shutil.ignore_patterns(
        ".git", ".venv", "build", "dist", "logs", "*.egg-info", "__pycache__", ".gpu-wheels"))  # no stale build/
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "-q", "-w",
                            str(tmp_path / "dist")], capture_output=True, text=True, timeout=600)
    if built.returncode and "setuptools" in built.stderr and not os.environ.get("CI"):  # pip's isolated build
        pytest.skip("needs a package index for the build's setuptools (pip's build isolation); CI has one")
    assert built.returncode == 0, built.stderr
    (wheel,) = (tmp_path / "dist").glob("cartpole_warp-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for packaged in ("cartpole_warp/usd/cartpole.usda", "cartpole_warp/usd/cartpole_dmc.usda",
                     *(f"cartpole_warp/configs/{preset.name}" for preset in (repo / "configs").glob("*.yaml")),
                     "cartpole_warp/rl/loop.py", "cartpole_warp/tasks/balance.py", "cartpole_warp/tasks/swingup.py",
                     "cartpole_warp/tools/bench.py"):
        assert packaged in names, packaged

    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    python = venv / "bin" / "python"
    venv_site = subprocess.run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               check=True, capture_output=True, text=True).stdout.strip()
    # the dependencies from this interpreter's site-packages (its .pth files, the editable checkout among them, are
    # not processed for a path listed in a .pth file)
    (tmp_path / venv_site / "dependencies.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    subprocess.run([python, "-m", "pip", "install", "--no-deps", "-q", str(wheel)], check=True, timeout=300)

    outside = tmp_path / "outside"
    outside.mkdir()
    script = (
        "import cartpole_warp, torch\n"
        "assert 'site-packages' in cartpole_warp.__file__, cartpole_warp.__file__\n"
        "for preset in ('default', 'tutorial'):\n"
        "    env = cartpole_warp.make_env(num_envs=8, preset=preset)\n"
        "    obs, *_ = env.step(torch.zeros(8, 1))\n"
        "    print(preset, env.env_dt, env.max_episode_length, tuple(obs.shape))\n"
        "env = cartpole_warp.tasks.make('cartpole-swingup', num_envs=8)\n"
        "print('swingup', env.max_episode_length, tuple(env.step(torch.zeros(8, 1))[0].shape))\n"
    )
    result = subprocess.run([python, "-c", script], cwd=outside, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "default 0.016666666666666666 600 (8, 4)" in result.stdout
    assert "tutorial 0.016666666666666666 2147483647 (8, 4)" in result.stdout
    assert "swingup 500 (8, 5)" in result.stdout, "the swing-up's stage ships in the wheel"

    result = subprocess.run([python, "-m", "cartpole_warp.train", "--task", "cartpole-swingup", "--num-envs", "64",
                             "--max-iterations", "1", "--logger", "none", "--log-dir", "runs"], cwd=outside,
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    (summary,) = (outside / "runs" / "rsl_rl" / "cartpole-swingup").rglob("summary.json")
    assert json.loads(summary.read_text())["iterations"] == 1


def test_the_library_changes_no_global_setting_and_hides_the_no_driver_warning(tmp_path):
    script = (
        "import logging, newton, warp as wp  # newton sets its own logger's level when imported\n"
        "before = (wp.config.log_level, logging.getLogger('newton').level)\n"
        "import cartpole_warp, torch\n"
        "env = cartpole_warp.make_env(num_envs=2)\n"
        "env.step(torch.zeros(2, 1))\n"
        "assert (wp.config.log_level, logging.getLogger('newton').level) == before, before\n"
        "print('stepped')\n"
    )
    result = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0 and "stepped" in result.stdout, result.stdout + result.stderr
    assert "Could not find or load the NVIDIA CUDA driver" not in result.stdout + result.stderr



def requirements(package: str, extra: str = "") -> list[Requirement]:
    """``package``'s requirements (this project's from pyproject.toml, another's as installed): its core ones, or
    (``extra``) those that only that extra adds."""
    if package == "cartpole_warp":
        import tomllib

        project = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]
        found = [Requirement(text) for text in project["dependencies"]]
        found += [Requirement(f"{text}; extra == '{name}'") for name, texts in project["optional-dependencies"].items()
                  for text in texts]
    else:
        found = [Requirement(text) for text in importlib.metadata.requires(package) or []]

    def wanted(requirement, name):
        return requirement.marker is None or requirement.marker.evaluate({"extra": name})

    return [r for r in found if wanted(r, extra) and not (extra and wanted(r, ""))]


def test_the_video_extra_caps_no_core_dependency_below_its_own_range():
    """``pip install '.[video]'`` (play.py's MP4s) downgrades nothing: no package it brings caps pillow below the
    newest release the core allows (moviepy 2.2, which gymnasium's RecordVideo needs, does: it is ``[gym-video]``)."""
    for requirement in requirements("cartpole_warp", "video"):
        optional_module(requirement.name.replace("-", "_"), VIDEO_EXTRA)  # their requirements: read where installed
    pillow = next(r for r in requirements("cartpole_warp") if r.name == "pillow")
    newest_allowed = max(v for v in ("11.3", "12.0", "13.0") if v in pillow.specifier)
    capped = [f"{r.name}: {inner}" for r in requirements("cartpole_warp", "video") for inner in requirements(r.name)
              if inner.name == "pillow" and newest_allowed not in inner.specifier]
    assert capped == []


def test_the_wheel_lists_every_package_folder():
    """pyproject names its packages one by one: a new layer's folder must be among them or the wheel leaves it out."""
    from pathlib import Path

    import tomllib

    root = Path(__file__).resolve().parents[1]
    listed = set(tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    folders = {".".join(path.parent.relative_to(root).parts) for path in (root / "cartpole_warp").rglob("__init__.py")}
    assert folders <= listed, f"not in pyproject's packages: {sorted(folders - listed)}"


def test_ci_runs_the_readmes_test_command_and_both_commands_install_torchs_cpu_build(repo):
    """The README's first lines are two commands for a fresh machine; ``.ci/run`` ends in exactly the test one, and
    both take torch's CPU build (PyPI's own Linux wheel brings the CUDA libraries)."""
    readme = (repo / "README.md").read_text().splitlines()
    commands = {line.split(":", 1)[0]: line.split("`")[1] for line in readme[:6] if line.startswith("Install and ")}
    assert commands.keys() == {"Install and train (fresh machine, CPU)", "Install and test"}, commands
    ci = (repo / ".ci" / "run").read_text().strip().splitlines()[-1]
    assert ci == commands["Install and test"]
    for command in commands.values():
        assert "pip install torch==2.13.0 --extra-index-url https://download.pytorch.org/whl/cpu && " in command
