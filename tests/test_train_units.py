"""Fast checks of the training plumbing: config precedence, the solved rule, the rsl-rl adapter, atomic writes,
run-folder lookup and the learning-curve PNG."""

import math
import os

import pytest
import torch
from PIL import Image
from tensordict import TensorDict

import cartpole_warp
from cartpole_warp.cli import apply_sets, config_reference
from cartpole_warp.config import ConfigError, TrainConfig, train_config
from cartpole_warp.metrics import EpisodeStats, is_solved
from cartpole_warp.render import plot_learning_curve
from cartpole_warp.rsl_rl_env import RslRlVecEnv
from cartpole_warp.runs import (RunError, atomic_write, create_run_dir, latest_checkpoint, latest_run, load_config,
                                save_config)
from cartpole_warp.trainer import runner_cfg


def test_preset_then_set_overrides_the_dataclass_defaults(tmp_path):
    preset = tmp_path / "p.yaml"
    preset.write_text("env:\n  num_envs: 64\nppo:\n  entropy_coef: 0.02\ntrain:\n  max_iterations: 7\n")
    cfg = train_config(str(preset))
    assert (cfg.env.num_envs, cfg.ppo.entropy_coef, cfg.train.max_iterations) == (64, 0.02, 7)
    apply_sets(cfg, ["ppo.entropy_coef=0.03", "policy.hidden_dims=[16, 8]", "env.task.episode_length_s=null"])
    assert cfg.ppo.entropy_coef == 0.03 and cfg.policy.hidden_dims == [16, 8] and cfg.env.task.episode_length_s is None
    assert TrainConfig().ppo.entropy_coef == 0.005


@pytest.mark.parametrize("assignment, message", [
    ("ppo.entropy=0.1", "unknown config key 'ppo.entropy'"),
    ("train.max_iterations=many", "expected int"),
    ("no_equals_sign", "KEY=VALUE"),
])
def test_bad_settings_name_the_key(assignment, message):
    with pytest.raises(ConfigError, match=message):
        apply_sets(TrainConfig(), [assignment])


def test_validate_rejects_mini_batches_that_do_not_divide_the_rollout():
    cfg = TrainConfig()
    cfg.env.num_envs, cfg.train.num_steps_per_env, cfg.ppo.num_mini_batches = 3, 3, 4
    with pytest.raises(ConfigError, match="num_mini_batches"):
        cfg.validate()


def test_every_config_field_is_documented_for_help():
    lines = config_reference()
    assert any(line.startswith("  ppo.entropy_coef (float, default 0.005): Weight") for line in lines)
    assert all(line.split("): ", 1)[1].strip() for line in lines), "a config field has no docstring"


def test_runner_cfg_maps_the_sections_onto_rsl_rl_keys():
    cfg = runner_cfg(TrainConfig())
    assert cfg["algorithm"]["class_name"] == "PPO" and cfg["algorithm"]["entropy_coef"] == 0.005
    assert cfg["actor"]["hidden_dims"] == [32, 32] and cfg["actor"]["distribution_cfg"]["init_std"] == 1.0
    assert cfg["num_steps_per_env"] == 16 and cfg["obs_groups"] == {"actor": ["policy"], "critic": ["policy"]}


def test_solved_needs_both_length_and_reward_per_step():
    assert is_solved(570, 0.9, 600)
    assert not is_solved(569, 0.99, 600)
    assert not is_solved(600, 0.89, 600)
    assert not is_solved(None, None, 600)


def test_episode_stats_average_per_episode():
    stats = EpisodeStats()
    stats.add(torch.tensor([10.0, -2.0]), torch.tensor([10.0, 1.0]), torch.tensor([True, False]))
    summary = stats.pop()
    assert summary.episodes == 2 and summary.mean_return == 4.0 and summary.mean_length == 5.5
    assert math.isclose(summary.mean_reward_per_step, (1.0 - 2.0) / 2) and summary.time_limit_fraction == 0.5
    assert stats.summary().episodes == 0


def test_adapter_follows_the_rsl_rl_vecenv_contract():
    env = RslRlVecEnv(cartpole_warp.make_env(num_envs=8, seed=1, task={"episode_length_s": 0.1}))
    assert (env.num_envs, env.num_actions, env.max_episode_length) == (8, 1, 6)
    obs = env.get_observations()
    assert isinstance(obs, TensorDict) and obs["policy"].shape == (8, 4) and obs.batch_size == torch.Size([8])
    env.episode_length_buf = torch.full((8,), 4, dtype=torch.int32)
    assert env.env.episode_length_buf.tolist() == [4] * 8
    obs, rewards, dones, extras = env.step(torch.zeros(8, 1))
    assert rewards.shape == (8,) and dones.shape == (8,) and not extras["time_outs"].any()
    obs, rewards, dones, extras = env.step(torch.zeros(8, 1))
    assert dones.tolist() == [1] * 8 and extras["time_outs"].all(), "episodes 4 steps in end at the 6-step limit"
    assert extras["episode"]["length"].tolist() == [6.0] * 8 and extras["episode"]["time_limit_fraction"].min() == 1
    assert obs["policy"].shape == (8, 4) and env.episode_length_buf.tolist() == [0] * 8
    assert env.episode_stats.pop().episodes == 8


def test_atomic_write_keeps_the_old_file_when_writing_fails(tmp_path):
    target = tmp_path / "model_3.pt"
    target.write_text("complete")

    def crash(tmp):
        with open(tmp, "w") as f:
            f.write("half")
        raise OSError("disk full")

    with pytest.raises(OSError):
        atomic_write(target, crash)
    assert target.read_text() == "complete" and os.listdir(tmp_path) == ["model_3.pt"]


def test_run_folders_are_found_newest_first(tmp_path):
    with pytest.raises(RunError, match="no checkpoint under .*run train.py first or pass --checkpoint"):
        latest_run(tmp_path, "rsl_rl", "cartpole")
    old = create_run_dir(tmp_path, "rsl_rl", "cartpole", "old")
    new = create_run_dir(tmp_path, "rsl_rl", "cartpole", "old")
    assert old != new and new.parent == tmp_path / "rsl_rl" / "cartpole"
    cfg = TrainConfig()
    cfg.env.num_envs = 32
    for run in (old, new):
        save_config(run, cfg)
        for it in (2, 10):
            (run / f"model_{it}.pt").write_bytes(b"x")
    assert latest_run(tmp_path, "rsl_rl", "cartpole") == new
    assert latest_checkpoint(new).name == "model_10.pt"
    assert load_config(new).env.num_envs == 32
    with pytest.raises(ConfigError):
        create_run_dir(tmp_path, "rsl_rl", "cartpole", "bad/name")


def test_learning_curve_png_decodes(tmp_path):
    history = [{"iteration": i, "reward": i / 10, "length": None if i == 0 else 3.0 * i} for i in range(10)]
    path = plot_learning_curve(tmp_path / "curve.png", history, [("reward", "reward", 0.9), ("length", "length", None)])
    image = Image.open(path)
    image.load()
    assert image.size == (900, 520) and len(image.getcolors(maxcolors=100000)) > 3
