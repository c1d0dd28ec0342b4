"""The promises at the edges (docs/library.md, docs/bad_input.md), each through the public API or a CLI as a user
meets it: one rule for presets wherever they are loaded, numbers that are numbers, stage errors that name the file,
the vector env's frames as a sequence, torchrun without GPUs, no run folder announced for a run that never started,
an empty stage path refused, a quiet console."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import cartpole_warp

REPO = Path(__file__).resolve().parent.parent
UNKNOWN_IN_PRESETS = [
    ("environment:\n  num_envs: 8\n", "unknown config key 'environment'"),
    ("agent:\n  algorithm:\n    clip: 0.1\n", "unknown config key 'agent.algorithm.clip'"),
    ("env:\n  sim:\n    solver: bullet\n", "sim.solver: Input should be 'featherstone' or 'mujoco'"),
    ("env:\n  task:\n    max_push_effort_n: yes\n", "task.max_push_effort_n: Input should be a valid number"),
    ("env:\n  task:\n    max_push_effort_n: '5'\n", "task.max_push_effort_n: Input should be a valid number"),
    ("console: fancy\n", "console: Input should be 'compact' or 'rsl_rl'"),
]
"""A preset's text and the error it must raise, whoever loads it."""


def train(*args, env=None, timeout=300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(REPO / "train.py"), *map(str, args)], cwd=REPO, capture_output=True,
                          text=True, timeout=timeout, env=env)


@pytest.mark.parametrize("text, message", UNKNOWN_IN_PRESETS)
def test_every_loader_of_a_preset_applies_one_rule(text, message, tmp_path, device):
    preset = tmp_path / "mine.yaml"
    preset.write_text(text)
    with pytest.raises(cartpole_warp.ConfigError, match=message):
        cartpole_warp.make_env(num_envs=2, device=device, preset=str(preset))
    with pytest.raises(cartpole_warp.ConfigError, match=message):
        gym.make("cartpole_warp/Cartpole-v0", preset=str(preset))
    if "env:" not in text:  # the env section is the task's: train.py finds the same errors there (below)
        with pytest.raises(cartpole_warp.ConfigError, match=message):
            cartpole_warp.tasks.env_config("cartpole-swingup", preset=str(preset))


@pytest.mark.parametrize("text, message", [UNKNOWN_IN_PRESETS[1], UNKNOWN_IN_PRESETS[3]])
def test_train_py_refuses_the_same_presets(text, message, tmp_path, run_main):
    preset = tmp_path / "mine.yaml"
    preset.write_text(text)
    result = run_main("train", "--config", preset, "--log-dir", tmp_path / "logs")
    assert result.returncode == 2 and message in result.stderr, result.stderr
    assert not (tmp_path / "logs").exists()


@pytest.mark.parametrize("value", [True, "5", "400", "none", float("nan"), [400.0]])
def test_float_fields_take_numbers_only(value):
    with pytest.raises(cartpole_warp.ConfigError, match="task.max_push_effort_n: Input should be a"):
        cartpole_warp.tasks.env_config("cartpole-balance", task={"max_push_effort_n": value})


def test_numbers_of_numpy_are_numbers():
    cfg = cartpole_warp.tasks.env_config("cartpole-balance", num_envs=np.int64(64), seed=np.int32(3),
                                         task={"max_push_effort_n": np.float32(20.0), "reset_dist_m": np.int64(2)})
    assert (cfg.num_envs, cfg.seed, cfg.task.max_push_effort_n, cfg.task.reset_dist_m) == (64, 3, 20.0, 2.0)
    assert type(cfg.num_envs) is int and type(cfg.task.max_push_effort_n) is float
    with pytest.raises(cartpole_warp.ConfigError, match="num_envs: Input should be a valid integer"):
        cartpole_warp.tasks.env_config("cartpole-balance", num_envs=np.float64(64.0))
    with pytest.raises(cartpole_warp.ConfigError, match="num_envs: Input should be a valid integer"):
        cartpole_warp.tasks.env_config("cartpole-balance", num_envs=np.bool_(True))


def test_an_empty_stage_path_is_refused():
    with pytest.raises(cartpole_warp.ConfigError, match="sim.stage_path: String should have at least 1 character"):
        cartpole_warp.tasks.env_config("cartpole-balance", sim={"stage_path": ""})


def test_the_vector_envs_frames_are_a_sequence(device):
    envs = gym.make_vec("cartpole_warp/Cartpole-v0", num_envs=4, vectorization_mode="vector_entry_point",
                        render_mode="rgb_array", device=device)
    envs.reset(seed=0)
    frames = envs.render()
    middle = frames[1:3]
    assert isinstance(middle, list) and len(middle) == 2 and len(frames[::2]) == 2 and frames[5:] == []
    np.testing.assert_array_equal(middle[0], frames[1])
    np.testing.assert_array_equal(frames[-1], frames[3])
    envs.close()


def test_torchrun_on_a_host_without_gpus_says_so(tmp_path):
    env = {**os.environ, "WORLD_SIZE": "2", "RANK": "0", "LOCAL_RANK": "0", "CUDA_VISIBLE_DEVICES": ""}
    result = train("--device", "cuda", "--num-envs", 64, "--log-dir", tmp_path, env=env)
    assert result.returncode == 2, result.stdout + result.stderr
    assert "torch sees no GPU on this host" in result.stderr and "processes per node" not in result.stderr


def test_a_run_that_never_starts_announces_no_run_folder(tmp_path, run_main):
    result = run_main("train", "--num-envs", 64, "--env.sim.stage-path", tmp_path / "missing.usda", "--log-dir",
                      tmp_path)
    assert result.returncode == 2 and "USD stage not found" in result.stderr
    assert "run folder" not in result.stdout and not list(tmp_path.rglob("config.yaml"))


def test_a_short_run_prints_its_iterations_summary_and_where_the_seconds_went(tmp_path):
    result = train("--num-envs", 64, "--max-iterations", 3, "--logger", "none", "--log-dir", tmp_path)
    assert result.returncode == 0, result.stderr
    assert "Could not find git repository" not in result.stdout + result.stderr
    assert "Resolved observation sets" not in result.stdout
    (summary,) = tmp_path.rglob("summary.json")
    timing = json.loads(summary.read_text())["timing_s"]
    expected = {"start", "config", "imports", "newton", "kernels", "scene", "capture", "eval_env", "networks",
                "training", "export", "curve"}
    assert set(timing) == expected and all(seconds >= 0 for seconds in timing.values())
    total = float(re.search(r"seconds: start .*; ([\d.]+) since the process started", result.stdout).group(1))
    assert sum(timing.values()) >= 0.9 * total, f"seconds outside every phase: {timing} of {total}"


@pytest.mark.skipif(os.environ.get("CARTPOLE_TEST_DEVICE", "cpu") != "cpu",
                    reason="on a GPU the CUDA-graph tests run: no skip to report")
def test_the_test_command_says_why_each_test_skips():
    """The README's test command (a plain ``python -m pytest``) names every skip and its reason, as the README
    promises, without ``-rs`` on the command line: here the GPU-only tests of one module on the CPU."""
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/test_cuda_graph.py",
                             "-k", "graphed_training"], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    skipped = r"SKIPPED \[\d+\] tests/test_cuda_graph.py:\d+: CUDA graphs need a GPU"
    assert re.search(skipped, result.stdout), result.stdout
