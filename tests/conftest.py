"""Shared fixtures: small envs on the test device with fixed seeds, fixed action sequences, the repository root.

Tests run on the CPU; ``CARTPOLE_TEST_DEVICE=cuda:0 pytest`` runs the env tests on a GPU instead.
"""

import contextlib
import importlib
import io
import logging
import os
import shutil
import subprocess
from pathlib import Path

import pytest
import torch

import cartpole_warp

DEVICE = os.environ.get("CARTPOLE_TEST_DEVICE", "cpu")


GB_PER_WORKER = 4
"""The most memory one test process has held (4.3 GB peak, the whole suite in one process, 2-core CPU)."""


def pytest_xdist_auto_num_workers(config) -> int:
    """``-n auto`` (the README's test command, through pyproject's addopts): one test process per core, as many as
    the available memory holds at ``GB_PER_WORKER`` each."""
    available_gb = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") / 1e9
    return max(1, min(len(os.sched_getaffinity(0)), int(available_gb // GB_PER_WORKER)))


ALL_CORES = os.sched_getaffinity(0)
"""The cores of the test run, before ``pytest_configure`` gives each test process its share."""


@contextlib.contextmanager
def on_all_cores():
    """Inside: this process (and what it starts) may use every core of the run."""
    share = os.sched_getaffinity(0)
    os.sched_setaffinity(0, ALL_CORES)
    try:
        yield
    finally:
        os.sched_setaffinity(0, share)


def pytest_configure(config):
    """A test process of pytest-xdist's ``-n N`` keeps its share of the cores (every N-th): the env's CPU shards,
    torch's threads and the processes a test starts then count the cores of their own process and do not fight the
    other test processes for theirs (oversubscribed cores slow both)."""
    worker, count = os.environ.get("PYTEST_XDIST_WORKER"), int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0"))
    cores = sorted(os.sched_getaffinity(0))
    if worker and 1 < count <= len(cores):
        share = cores[int(worker.removeprefix("gw")) % count::count]
        os.sched_setaffinity(0, share)
        torch.set_num_threads(len(share))


SLOWEST_FILES_FIRST = ("test_train_cli.py", "test_startup.py", "test_env.py", "test_browser.py", "test_rendering.py",
                       "test_physics.py", "test_apg.py", "test_packaging.py", "test_population.py", "test_sapg.py",
                       "test_sweep.py", "test_in_step.py", "test_viewer.py", "test_sb3_env.py", "test_gym_env.py",
                       "test_promises.py", "test_examples.py", "test_multiarm.py", "test_distributed.py",
                       "test_sysid.py", "test_reproducible.py")
"""The test files that take longest, longest first (measured: --durations=0): pyproject's ``--dist loadfile
--no-loadscope-reorder`` hands whole files to the test processes in this order, so that they end together."""


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(SLOWEST_FILES_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: each file's tests keep their order


@pytest.fixture(scope="session")
def device() -> str:
    """The device the env tests run on."""
    return DEVICE


@pytest.fixture(scope="session")
def repo() -> Path:
    """The repository root."""
    return Path(__file__).resolve().parent.parent


def call_main(script: str, *args) -> subprocess.CompletedProcess:
    """``cartpole_warp.<script>.main(args)`` (train or play) in the test process, as the script calls it; a
    ``CompletedProcess`` of its exit code and output, like a run of the script without the seconds a fresh process
    spends importing Newton and torch."""
    main = importlib.import_module(f"cartpole_warp.{script}").main
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main([str(arg) for arg in args])
        except SystemExit as stop:
            code = stop.code
        finally:
            logging.getLogger("cartpole_warp").handlers.clear()  # bound to this call's stdout
    return subprocess.CompletedProcess(args, code, out.getvalue(), err.getvalue())


def collect(runner):
    """One rollout of ``runner``'s policy into its PPO storage, and the returns (rsl-rl's loop, without the rest of
    an iteration)."""
    obs = runner.env.get_observations()
    with torch.inference_mode():
        for _ in range(runner.rsl_rl_cfg["num_steps_per_env"]):
            obs, rewards, dones, extras = runner.env.step(runner.learner.alg.act(obs))
            runner.learner.alg.process_env_step(obs, rewards, dones, extras)
        runner.learner.alg.compute_returns(obs)
    return obs


@pytest.fixture
def run_main():
    """``run_main(script, *args)``: ``call_main``, as a fixture."""
    return call_main


def sees_images(task: str) -> bool:
    """Whether registered task ``task`` observes camera frames."""
    return cartpole_warp.tasks.env_config(task).camera.enabled


@pytest.fixture
def make():
    """``make(num_envs=64, seed=0, preset="default", task_name=None, **overrides)``: an env of task ``task_name`` (a
    registered name; None: the default task, cartpole-balance) on the test device from a preset with nested overrides
    (sim={...}, task={...}: ``task`` is the task's settings; a camera task's frames ``SMALL_FRAMES`` unless
    camera={...} says otherwise); every env made is closed after the test."""
    envs = []

    def factory(num_envs=64, seed=0, preset="default", task_name=None, **overrides):
        name = task_name or cartpole_warp.tasks.DEFAULT_TASK
        if sees_images(name):
            overrides["camera"] = SMALL_FRAMES | overrides.get("camera", {})
        env = cartpole_warp.tasks.make(name, num_envs=num_envs, device=DEVICE, seed=seed, preset=preset, **overrides)
        envs.append(env)
        return env

    yield factory
    for env in envs:
        env.close()


SMALL_FRAMES = {"width_px": 16, "height_px": 12}
"""The frames of a camera task in machinery tests (the machinery does not depend on the size; the CPU renders 64x64
frames ~20x slower); tests of the pictures themselves use the task's own."""
TRAINING_FRAMES = {"width_px": 36, "height_px": 36}
"""The frames of a camera task in a machinery test that trains: the smallest its encoder takes."""


@pytest.fixture
def random_actions():
    """``random_actions(num_envs, steps, seed=0, scale=1.5)``: a fixed (steps, num_envs, 1) action sequence on the
    test device, partly outside [-1, 1]."""

    def actions(num_envs, steps, seed=0, scale=1.5):
        gen = torch.Generator().manual_seed(seed)
        return ((torch.rand((steps, num_envs, 1), generator=gen) * 2 - 1) * scale).to(DEVICE)

    return actions


SB3_EXTRA = "pip install -e '.[sb3]'"
VIDEO_EXTRA = "pip install -e '.[video]'"


def optional_module(name: str, install: str):
    """``pytest.importorskip(name)`` whose reason is the install line; where ``CI`` is set the ImportError fails
    instead (.ci/run installs every extra the tests use)."""
    if os.environ.get("CI"):
        return importlib.import_module(name)
    return pytest.importorskip(name, reason=f"needs {name.split('.')[0]}: {install}")


def writes_mp4() -> bool:
    """Whether this machine writes MP4s (the video extra: imageio with its ffmpeg); fails where ``CI`` is set and it
    does not."""
    from cartpole_warp.viz.record import video_available

    if not video_available() and os.environ.get("CI"):
        pytest.fail(f"needs the video extra: {VIDEO_EXTRA} (.ci/run installs it; CI is set)")
    return video_available()


def requires_mp4():
    """Skip the test, with the install line, where this machine writes no MP4 (``writes_mp4``)."""
    if not writes_mp4():
        pytest.skip(f"needs the video extra (imageio with its ffmpeg): {VIDEO_EXTRA}")


def system_command(name: str, install: str) -> str:
    """The path of system command ``name``; where it is missing, the test skips with the install line (fails where
    ``CI`` is set: .ci/run installs it)."""
    path = shutil.which(name)
    if path is None:
        message = f"needs {name}: {install}"
        if os.environ.get("CI"):
            pytest.fail(f"{message} (.ci/run installs it; CI is set)")
        pytest.skip(message)
    return path
