"""Fast checks of the training plumbing: config precedence and errors, --help, the rsl-rl config, the solved rule,
episode statistics, the rsl-rl adapter, atomic writes, run-folder lookup and the learning-curve PNG."""

import ast
import contextlib
import dataclasses
import inspect
import io
import math
import os
import time

import pytest
import torch
from PIL import Image
from rsl_rl.utils import resolve_callable
from tensordict import TensorDict

import cartpole_warp
from cartpole_warp import tasks
from cartpole_warp.config import ConfigError
from cartpole_warp.files import atomic_write
from cartpole_warp.rl.config import RunnerConfig, train_config
from cartpole_warp.rl.curve import plot_learning_curve
from cartpole_warp.rl.runner import CartpoleRunner, to_rsl_rl
from cartpole_warp.rl.runs import (
    RunError,
    latest_checkpoint,
    latest_run,
    load_config,
    new_run_dir,
    save_config,
)
from cartpole_warp.statistics import EpisodeStats, EpisodeSummary
from cartpole_warp.train import resolve
from cartpole_warp.wrappers.rsl_rl import RslRlVecEnv, mirror


def test_preset_then_flags_override_the_dataclass_defaults(tmp_path):
    preset = tmp_path / "p.yaml"
    preset.write_text("env:\n  num_envs: 64\nagent:\n  max_iterations: 7\n  algorithm:\n    entropy_coef: 0.02\n")
    cfg = train_config(preset=str(preset))
    assert (cfg.env.num_envs, cfg.agent.algorithm.entropy_coef, cfg.agent.max_iterations) == (64, 0.02, 7)
    cfg, run_dir, checkpoint = resolve(["--config", str(preset), "--agent.algorithm.entropy-coef", "0.03",
                                        "--agent.actor.hidden-dims", "16", "8", "--env.task.episode-length-s", "None",
                                        "--log-dir", str(tmp_path), "--run-name", "x"])
    assert cfg.agent.algorithm.entropy_coef == 0.03 and cfg.agent.actor.hidden_dims == [16, 8]
    assert cfg.env.task.episode_length_s is None and cfg.env.num_envs == 64 and cfg.agent.max_iterations == 7
    assert run_dir.parent == tmp_path / "rsl_rl" / "cartpole-balance" and run_dir.name.endswith("_x")
    assert checkpoint is None and not run_dir.exists()
    assert train_config().agent.algorithm.entropy_coef == 0.005


@pytest.mark.parametrize("yaml_text, message", [
    ("agent:\n  algorithm:\n    entropy: 0.1\n", "unknown config key 'agent.algorithm.entropy'; valid keys here: "),
    ("agent:\n  max_iterations: many\n", "agent.max_iterations: Input should be a valid integer"),
    ("env:\n  sim:\n    solver: bullet\n", "env.sim.solver: Input should be 'featherstone' or 'mujoco'"),
    ("no_such_section: 1\n", "unknown config key 'no_such_section'"),
    ("env:\n  num_envs: true\n", "env.num_envs: Input should be a valid integer"),
    ("agent:\n  algorithm:\n    gamma: 2.0\n", "agent.algorithm.gamma: Input should be less than or equal to 1"),
    ("- a list\n", "expected a mapping at the top level"),
])
def test_bad_presets_name_the_key(tmp_path, yaml_text, message):
    preset = tmp_path / "bad.yaml"
    preset.write_text(yaml_text)
    with pytest.raises(ConfigError, match=message):
        train_config(preset=str(preset))


def test_a_preset_with_several_bad_keys_names_every_one(tmp_path):
    preset = tmp_path / "bad.yaml"
    preset.write_text("env:\n  num_env: 8\n  sim:\n    solver: bullet\nagent:\n  max_iteration: 5\n")
    for build in (lambda: train_config(preset=str(preset)),
                  lambda: tasks.env_config("cartpole-balance", str(preset))):
        with pytest.raises(ConfigError) as err:
            build()
        for key in ("'agent.max_iteration'", "'env.num_env'", "env.sim.solver: Input should be"):
            assert key in str(err.value)
        assert "\n" not in str(err.value)


def test_validate_rejects_mini_batches_that_do_not_divide_the_rollout():
    cfg = train_config()
    cfg.env.num_envs, cfg.agent.num_steps_per_env, cfg.agent.algorithm.num_mini_batches = 3, 3, 4
    with pytest.raises(ConfigError, match="num_mini_batches"):
        cfg.validate()


def field_docs(cls) -> dict[str, str]:
    """The docstring under each field of a dataclass (read here with ast, independently of tyro)."""
    docs = {}
    for klass in reversed(cls.__mro__[:-1]):
        body = ast.parse(inspect.getsource(klass)).body[0].body
        for node, after in zip(body, body[1:]):
            documented = isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
            if isinstance(node, ast.AnnAssign) and documented:
                docs[node.target.id] = " ".join(after.value.value.split())
    return docs


def leaf_fields(cfg, prefix=""):
    """(flag, docstring) of every non-dataclass field of a config tree (read from the instance: generic fields hold
    the task's settings)."""
    docs = field_docs(type(cfg))
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        if dataclasses.is_dataclass(value):
            yield from leaf_fields(value, f"{prefix}{f.name}.")
        else:
            yield f"--{prefix}{f.name}".replace("_", "-"), docs.get(f.name)


@pytest.mark.parametrize("task", tasks.names())
def test_help_all_lists_every_config_field_with_its_docstring_and_the_tasks(task):
    help_text = io.StringIO()
    with contextlib.redirect_stdout(help_text), pytest.raises(SystemExit) as exit_code:
        resolve(["--task", task, "--help-all"])
    assert exit_code.value.code == 0
    text = " ".join(help_text.getvalue().replace("│", " ").split())
    fields = list(leaf_fields(train_config(task)))
    assert len(fields) > 40
    for flag, doc in fields:
        assert doc, f"{flag} has no docstring"
        assert flag in text, flag
        assert " ".join(doc.split()[:4]) in text, f"{flag}: its docstring is not in --help"
    for flag in ("--num-envs", "--device", "--seed", "--max-iterations", "--run-name", "--log-dir", "--config",
                 "--resume", "--checkpoint", "--logger", "--stop-when-solved", "--task"):
        assert flag in text, flag
    for name in tasks.names():
        assert f"{name} {tasks.get(name).summary}" in text, f"--help lists the task {name}"


def test_runner_config_is_rsl_rl_train_cfg():
    cfg = to_rsl_rl(RunnerConfig())
    assert cfg["algorithm"]["class_name"] == "cartpole_warp.rl.ppo:SyncFreePPO"
    assert cfg["algorithm"]["entropy_coef"] == 0.005
    assert cfg["actor"]["class_name"] == cfg["critic"]["class_name"] == "MLPModel"
    assert cfg["actor"]["hidden_dims"] == [32, 32] and cfg["actor"]["distribution_cfg"] == {
        "class_name": "cartpole_warp.rl.ppo:SyncFreeGaussian", "init_std": 1.0}
    assert cfg["num_steps_per_env"] == 8 and cfg["obs_groups"] == {"actor": ["policy"], "critic": ["policy"]}
    assert "max_iterations" not in cfg and cfg["logger"] == "tensorboard"
    assert to_rsl_rl(RunnerConfig(logger="none"))["logger"]["class_name"].endswith(":NullLogWriter")
    assert "symmetry_cfg" not in cfg["algorithm"], "no mirror, no symmetry"
    symmetry = to_rsl_rl(RunnerConfig(), mirror=True)["algorithm"]["symmetry_cfg"]
    assert resolve_callable(symmetry["data_augmentation_func"]) is mirror and symmetry["use_data_augmentation"]
    isaac_lab = train_config(preset="isaac_lab").agent
    assert to_rsl_rl(isaac_lab)["algorithm"]["class_name"] == "PPO"
    assert to_rsl_rl(isaac_lab)["actor"]["distribution_cfg"]["class_name"] == "GaussianDistribution"
    assert (isaac_lab.num_steps_per_env, isaac_lab.algorithm.num_learning_epochs, isaac_lab.algorithm.num_mini_batches,
            isaac_lab.algorithm.desired_kl) == (16, 5, 4, 0.01)
    assert isaac_lab.actor.activation == isaac_lab.critic.activation == "elu", "Isaac Lab's cartpole uses ELU"


def summary(time_limit_fraction, per_step, full_per_step=None):
    return EpisodeSummary(1, None, None, per_step, time_limit_fraction, int(full_per_step is not None), full_per_step)


def test_the_balance_task_is_solved_by_time_limit_fraction_and_reward_per_step():
    solved = tasks.get("cartpole-balance").solved
    assert solved(summary(0.95, 0.9))
    assert not solved(summary(0.949, 0.99))
    assert not solved(summary(1.0, 0.89))
    assert not solved(EpisodeSummary(0, None, None, None, None))


def test_the_swingup_is_solved_by_the_reward_per_step_of_full_episodes():
    solved = tasks.get("cartpole-swingup").solved
    assert solved(summary(0.1, 0.1, full_per_step=0.8)), "short first episodes do not count against it"
    assert not solved(summary(1.0, 0.95)), "no full episode: not solved"
    assert not solved(summary(1.0, 0.9, full_per_step=0.79))


def test_episode_stats_average_the_ended_episodes_and_the_full_ones():
    stats = EpisodeStats("cpu", max_episode_length=10)
    ended = torch.tensor([True, True, False])
    stats.add(ended, torch.tensor([10.0, -2.0, 99.0]), torch.tensor([10, 1, 10]), torch.tensor([True, False, True]))
    summary = stats.pop()
    assert summary.episodes == 2 and summary.mean_return == 4.0 and summary.mean_episode_length == 5.5
    assert math.isclose(summary.mean_reward_per_step, (1.0 - 2.0) / 2) and summary.time_limit_fraction == 0.5
    assert summary.full_episodes == 1 and summary.full_reward_per_step == 1.0
    assert stats.summary().episodes == 0 and stats.summary().mean_return is None


@pytest.mark.parametrize("task", tasks.names())
def test_adapter_follows_the_rsl_rl_vecenv_contract(task):
    env = RslRlVecEnv(tasks.make(task, num_envs=8, seed=1, sim={"physics_dt": 1 / 120, "decimation": 2},
                                 task={"episode_length_s": 0.1}))
    num_obs = env.env.num_obs
    assert (env.num_envs, env.num_actions, env.max_episode_length) == (8, 1, 6)
    obs = env.get_observations()
    assert isinstance(obs, TensorDict) and obs["policy"].shape == (8, num_obs) and obs.batch_size == torch.Size([8])
    env.episode_length_buf = torch.full((8,), 4, dtype=torch.int32)
    assert env.env.episode_length_buf.tolist() == [4] * 8
    obs, rewards, dones, extras = env.step(torch.zeros(8, 1))
    assert rewards.shape == (8,) and dones.shape == (8,) and dones.dtype == torch.int64
    assert not extras["time_outs"].any()
    obs, rewards, dones, extras = env.step(torch.zeros(8, 1))
    assert dones.tolist() == [1] * 8 and extras["time_outs"].all(), "counters set to 4 reach the 6-step limit"
    assert extras["episode_length"].tolist() == [2] * 8, "the reported length is the steps really run"
    assert extras["final_obs"].shape == (8, num_obs)
    assert obs["policy"].shape == (8, num_obs) and env.episode_length_buf.tolist() == [0] * 8


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


def test_run_folders_are_found_newest_first_in_their_experiment(tmp_path):
    with pytest.raises(RunError, match="no checkpoint under .*run train.py first or pass --checkpoint"):
        latest_run(tmp_path, "cartpole-swingup")
    old = new_run_dir(tmp_path, "cartpole-swingup", "old")
    old.mkdir(parents=True)
    new = new_run_dir(tmp_path, "cartpole-swingup", "old")
    new.mkdir()
    assert old != new and new.parent == tmp_path / "rsl_rl" / "cartpole-swingup"
    cfg = train_config("cartpole-swingup")
    cfg.env.num_envs = 32
    for run in (old, new):
        save_config(run, cfg)
        for it in (2, 10):
            (run / f"model_{it}.pt").write_bytes(b"x")
    assert latest_run(tmp_path, "cartpole-swingup") == new
    assert latest_checkpoint(new).name == "model_10.pt"
    loaded = load_config(new)
    assert loaded.env.num_envs == 32 and loaded.task == "cartpole-swingup"
    assert type(loaded.env.task) is tasks.get("cartpole-swingup").env_class.config_class
    with pytest.raises(RunError, match="experiments there: cartpole-swingup"):
        latest_run(tmp_path, "cartpole-balance")
    with pytest.raises(ConfigError):
        new_run_dir(tmp_path, "cartpole-swingup", "bad/name")


@pytest.mark.parametrize("task", tasks.names())
def test_learning_curve_png_decodes(tmp_path, task):
    history = [{"iteration": i, "episodes": i, "mean_reward_per_step": i / 10, "time_limit_fraction": i / 9,
                "full_reward_per_step": i / 11 if i > 4 else None} for i in range(10)]
    for i in (4, 9):
        history[i]["evaluation"] = {"mean_reward_per_step": i / 9, "time_limit_fraction": i / 9,
                                    "full_reward_per_step": i / 9}
    path = plot_learning_curve(tmp_path / "curve.png", history, solved=tasks.get(task).solved)
    image = Image.open(path)
    image.load()
    assert image.size == (800, 600) and len(image.getcolors(maxcolors=100000)) > 50


def test_sweep_variants_are_train_flags_and_failed_runs_count_as_unsolved():
    from cartpole_warp.tools.sweep import RunResult, seed_row, table, variant_flags

    flags = variant_flags("config=isaac_lab agent.no-cuda-graph agent.actor.hidden-dims=64,64")
    assert flags == ["--config", "isaac_lab", "--agent.no-cuda-graph", "--agent.actor.hidden-dims", "64", "64"]
    cfg, _, _ = resolve(flags)
    agent = cfg.agent
    assert (agent.cuda_graph, agent.actor.hidden_dims, agent.algorithm.class_name) == (False, [64, 64], "PPO")
    results = [RunResult("a=1", 0, 50, 1.0, 100, 3.0, 4.5, 0.98, 0.99, 2, 0.31),
               RunResult("a=1", 1, None, None, None, error="x"), RunResult("b", 0, None, None, 50)]
    rows = table(results, ["a=1", "b"], seeds=2, task="cartpole-balance").splitlines()
    assert "play: time_limit_fraction (min)" in rows[0]
    assert rows[2:] == ["| `--a 1` | 1/2 (1 failed) | 50 / 50 | 1.0 / 1.0 | 3.0 + 4.5 | 100 | 0.990 |",
                        "| `--b` | 0/2 | - | - | - | 50 | - |"]
    assert [seed_row(r) for r in results] == ["| `--a 1` | 0 | 50 | 1.0 | 3.0 + 4.5 | 100 | 2, 0.3 | 0.980 | 0.990 |",
                                              "| `--a 1` | 1 | failed | - | - | - | - | - | - |",
                                              "| `--b` | 0 | not solved | - | - | 50 | - | - | - |"]


def test_a_sweep_in_one_process_repeats_a_seed_exactly_and_plays_it(tmp_path, capsys):
    """Runs in the sweep's own process leave nothing behind that changes the next: the same seed twice gives the same
    networks, and play's metric appears next to the run's."""
    from cartpole_warp.tools.sweep import main

    assert main(["--seeds", "3", "3", "--num-envs", "64", "--max-iterations", "3", "--play",
                 "--log-dir", str(tmp_path)]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| (default) | 3 |")]
    assert len(rows) == 2 and rows[0].split("|")[-2].strip() != "-", rows
    checkpoints = sorted(tmp_path.rglob("model_2.pt"))
    assert len(checkpoints) == 2
    first, second = (torch.load(path, weights_only=False) for path in checkpoints)
    for name, value in first["actor_state_dict"].items():
        assert torch.equal(value, second["actor_state_dict"][name]), name


@pytest.mark.parametrize("spread", [False, True])
def test_random_episode_starts_spread_time_outs_and_report_true_lengths(spread):
    cfg = train_config()
    cfg.env.num_envs, cfg.env.task.episode_length_s, cfg.agent.num_steps_per_env = 64, 0.1, 12
    torch.manual_seed(0)
    env = RslRlVecEnv(cartpole_warp.make_env(num_envs=64, seed=0, task={"episode_length_s": 0.1}))
    runner = CartpoleRunner(env, cfg, None)
    runner.learn(1, init_at_random_ep_len=spread)
    first = runner.progress.history[0]
    assert first["time_limit_fraction"] > 0.95, "a 6-step limit ends nearly every episode by time"
    if spread:
        assert first["mean_episode_length"] < 5.5, "first episodes cut short by their random counters say so"
    else:
        assert first["mean_episode_length"] > 5.8


def test_phase_clock_times_each_phase_on_its_device(device):
    """On the CPU the host clock; on a GPU CUDA events, which time the device's work, not the host's queueing."""
    from cartpole_warp.streams import PhaseClock

    if device.startswith("cuda"):
        matrix = torch.randn(4096, 4096, device=device)

        def work(units):
            for _ in range(units):
                matrix @ matrix
    else:
        def work(units):
            time.sleep(0.01 * units)
    clock = PhaseClock(device, phases=2)
    clock.mark(0)
    work(1)
    clock.mark(1)
    work(20)
    clock.mark(2)
    first, second = clock.seconds()
    assert 0 < first < second and second > 5 * first


def test_play_loads_the_checkpoints_actor_alone_and_acts_as_the_runner(tmp_path):
    """``load_policy`` (play's, no runner or optimizer) builds the actor as rsl-rl does: the same actions as the
    runner's policy for the same checkpoint, and a clear error for networks that do not fit."""
    from cartpole_warp.rl.runner import load_policy

    cfg = train_config()
    cfg.env.num_envs = 16
    env = RslRlVecEnv(cartpole_warp.make_env(num_envs=16, seed=0))
    torch.manual_seed(0)
    runner = CartpoleRunner(env, cfg, None)
    runner.learn(2)
    runner.save(str(tmp_path / "model.pt"))
    obs = torch.randn(16, env.env.num_obs)
    with torch.inference_mode():
        assert torch.equal(load_policy(env, cfg.agent, tmp_path / "model.pt")(obs), runner.policy()(obs))
    cfg.agent.actor.hidden_dims = [8]
    with pytest.raises(RunError, match="does not match the configured networks"):
        load_policy(env, cfg.agent, tmp_path / "model.pt")


def test_an_iteration_in_which_no_episode_ended_says_how_long_they_have_run(capsys):
    """A balancing policy ends no episode for many iterations; its console row says the envs are still running and
    for how long, not only that nothing finished."""
    cfg = train_config()
    cfg.env.num_envs, cfg.agent.num_steps_per_env = 16, 2
    torch.manual_seed(0)
    runner = CartpoleRunner(RslRlVecEnv(cartpole_warp.make_env(num_envs=16, seed=0)), cfg, None)
    runner.learn(2)
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("it ")]
    dt = cfg.env.sim.env_dt
    assert [row.split(" | ")[1].strip() for row in rows] == [
        f"no episode ended; 16 running, {2 * dt:5.2f} s in on average",
        f"no episode ended; 16 running, {4 * dt:5.2f} s in on average"], rows
