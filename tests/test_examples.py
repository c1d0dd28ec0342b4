"""The tutorial's SB3 scripts in examples/: training writes the tutorial's artefacts, and playing the model reproduces
a rollout of the same model computed here with SB3 and the gymnasium env directly."""

import re
import subprocess
import sys

import pytest
from conftest import SB3_EXTRA, optional_module

from cartpole_warp import TaskGymEnv

PPO = optional_module("stable_baselines3", SB3_EXTRA).PPO


def run_example(repo, name, *args, cwd):
    result = subprocess.run([sys.executable, str(repo / "examples" / name), *map(str, args)], cwd=cwd,
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    return result.stdout


@pytest.fixture(scope="module")
def trained_model(repo, tmp_path_factory):
    """examples/sb3_cartpole_train.py for 2000 steps (two of the tutorial's 1000-step rollouts)."""
    work = tmp_path_factory.mktemp("sb3")
    stdout = run_example(repo, "sb3_cartpole_train.py", "--total-timesteps", 2000, cwd=work)
    return work, stdout


def test_train_example_writes_the_tutorials_artefacts(trained_model):
    work, stdout = trained_model
    assert re.search(r"total_timesteps\s*\|\s*2000", stdout), stdout
    assert (work / "logs/sb3/ppo_cartpole.zip").is_file()
    assert list((work / "logs/sb3/cartpole_tensorboard").rglob("events.out.tfevents.*"))
    model = PPO.load(work / "logs/sb3/ppo_cartpole")
    assert model.num_timesteps == 2000
    assert (model.n_steps, model.batch_size, model.n_epochs, model.gamma) == (1000, 1000, 20, 0.99)


def test_play_example_replays_the_model_like_sb3_on_the_gymnasium_env(repo, trained_model):
    work, _ = trained_model
    stdout = run_example(repo, "sb3_cartpole_play.py", "--steps", 300, "--seed", 1, cwd=work)
    printed = [(float(r), int(n)) for r, n in re.findall(r"return (-?\d+\.\d), (\d+) steps", stdout)]

    model, env = PPO.load(work / "logs/sb3/ppo_cartpole"), TaskGymEnv(preset="tutorial", seed=1)
    obs, _ = env.reset()
    expected, ret, length = [], 0.0, 0
    for _ in range(300):
        obs, reward, terminated, truncated, _ = env.step(model.predict(obs, deterministic=True)[0])
        ret, length = ret + reward, length + 1
        if terminated or truncated:
            expected.append((ret, length))
            ret, length = 0.0, 0
    assert f"still running after {length} steps" in stdout
    assert [n for _, n in printed] == [n for _, n in expected]
    assert [r for r, _ in printed] == pytest.approx([r for r, _ in expected], abs=0.051)


def test_play_example_without_a_model_says_how_to_make_one(repo, tmp_path):
    result = subprocess.run([sys.executable, str(repo / "examples" / "sb3_cartpole_play.py")], cwd=tmp_path,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr
    assert "error: no model at logs/sb3/ppo_cartpole.zip" in result.stderr
    assert "python examples/sb3_cartpole_train.py" in result.stderr
