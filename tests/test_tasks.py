"""The task seam: the registry finds the task modules, builds any task by name, names the known ones when asked for an
unknown one, and a task defined outside the package (one module's worth: settings, Warp functions, env class,
``register``) trains, plays and reaches gymnasium with no machinery file touched."""

import dataclasses
import importlib
import math
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import pytest
import torch
import warp as wp

from cartpole_warp import tasks
from cartpole_warp.engine.kernels import END_NONE, TaskFunctions
from cartpole_warp.evaluation.rollouts import rollout
from cartpole_warp.rl.config import device_defaults, train_config
from cartpole_warp.rl.loop import TrainingLoop
from cartpole_warp.settings.config import ConfigError, NonNegative
from cartpole_warp.tasks.cart_base import CartpoleConfig, CartTaskEnv
from cartpole_warp.wrappers.gymnasium import register_envs
from cartpole_warp.wrappers.rsl_rl import RslRlVecEnv


def test_the_registry_finds_every_task_and_names_the_known_ones():
    assert tasks.names() == ["cartpole-balance", "cart-double-pole-balance", "cart-double-pole-balance-rgb",
                             "cart-three-pole-swingup",
                             "cart-two-pole-swingup", "cartpole-balance-depth", "cartpole-balance-rgb",
                             "cartpole-balance-sparse", "cartpole-swingup", "cartpole-swingup-rgb",
                             "cartpole-swingup-sparse"]
    with pytest.raises(ConfigError, match="unknown task 'cartpole-moonwalk'; known tasks: cartpole-balance, "
                                          "cart-double-pole-balance, cart-double-pole-balance-rgb, "):
        tasks.make("cartpole-moonwalk")
    balance, swingup, double = (tasks.make(name, num_envs=2) for name in
                                ("cartpole-balance", "cartpole-swingup", "cart-double-pole-balance"))
    assert (balance.num_obs, swingup.num_obs, double.num_obs) == (4, 5, 6)
    assert double.joint_roles == ("cart", "pole", "pole2") and double.scene.dofs_per_env == 3
    assert len({type(balance), type(swingup), type(double)}) == 3
    assert swingup.max_episode_length == 500 and balance.max_episode_length == double.max_episode_length == 600


def test_the_docs_task_table_lists_every_task_its_gymnasium_ids_its_budget_and_its_device_settings(repo):
    """docs/tasks.md: a row per task of the package, with its gymnasium ids, its default budget of iterations and
    whether it takes settings of its own on a GPU and on a CPU."""
    rows = {}
    for line in (repo / "docs" / "tasks.md").read_text().splitlines():
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        if line.startswith("| `") and len(cells) == 5:
            rows[cells[0].strip("`")] = cells
    shipped = [name for name in tasks.names() if tasks.get(name).env_class.__module__.startswith("cartpole_warp.")]
    assert sorted(rows) == sorted(shipped)
    for name in shipped:
        ids = {gym_id.strip("`") for gym_id in rows[name][1].split(", ")}
        assert ids == set(tasks.get(name).gym_ids), name
        assert rows[name][2] == str(train_config(name).agent.max_iterations), name
        assert (rows[name][3] != "-") == bool(device_defaults(tasks.get(name), "cuda")), name
        assert (rows[name][4] != "-") == bool(device_defaults(tasks.get(name), "cpu")), name


def test_a_preset_for_another_task_is_refused_alike_by_every_entry_point(tmp_path, run_main):
    preset = tmp_path / "swing.yaml"
    preset.write_text("task: cartpole-swingup\nagent:\n  max_iterations: 3\nenv:\n  num_envs: 8\n")
    assert train_config("cartpole-swingup", str(preset)).agent.max_iterations == 3
    assert tasks.env_config("cartpole-swingup", str(preset)).num_envs == 8
    refusal = "is for task 'cartpole-swingup', not 'cartpole-balance'"
    for build in (lambda: train_config("cartpole-balance", str(preset)),
                  lambda: tasks.env_config("cartpole-balance", str(preset)),
                  lambda: tasks.make("cartpole-balance", preset=str(preset)),
                  lambda: gym.make("cartpole_warp/Cartpole-v0", preset=str(preset))):
        with pytest.raises(ConfigError, match=refusal):
            build()
    result = run_main("train", "--config", preset, "--log-dir", tmp_path)
    assert result.returncode != 0 and refusal in result.stderr and "Traceback" not in result.stderr
    for name in ("isaac_lab", "tutorial"):  # the balance's timings: refused for the swing-up, not applied silently
        with pytest.raises(ConfigError, match=f"preset '{name}' is for task 'cartpole-balance'"):
            tasks.env_config("cartpole-swingup", name)


def test_the_env_config_of_a_task_is_validated_where_it_is_built():
    with pytest.raises(ConfigError, match="num_envs=16,777,217"):
        tasks.env_config("cartpole-balance", num_envs=16_777_217)
    with pytest.raises(ConfigError, match="reset_pole_angle_rad"):
        tasks.env_config("cartpole-balance", task={"reset_pole_angle_rad": 2.0})


@dataclass
class HoldStillConfig(CartpoleConfig):
    """A third task written as a newcomer would: keep the cart at the centre, the pole hanging still."""

    max_push_effort_n: NonNegative = 20.0
    """Cart force (N) for action 1."""



@wp.func
def observe(q: wp.vec2, qd: wp.vec2, p: Any):
    return wp.vec3(q[0], qd[0], qd[1])


@wp.func
def reward_and_end(q: wp.vec2, qd: wp.vec2, action: wp.types.vector(1, float), p: Any):
    return wp.exp(-q[0] * q[0] - qd[1] * qd[1]), END_NONE


@wp.func
def sample_reset(rng_state: wp.array(dtype=wp.uint32), env: int, p: Any):
    s = rng_state[env]
    start = wp.vec2(wp.randf(s, -0.5, 0.5), wp.pi)
    rng_state[env] = s
    return start, wp.vec2(0.0, 0.0)


@wp.func
def joint_forces(action: wp.types.vector(1, float), p: Any, forces: wp.vec2):
    return wp.vec2(p.max_push_effort_n * action[0], 0.0)


class HoldStillEnv(CartTaskEnv):
    """observation (N, 3) [cart_pos, cart_vel, pole_vel]; reward exp(-cart_pos^2 - pole_vel^2); never terminates."""

    config_class = HoldStillConfig
    num_obs = 3
    stage = "cartpole_dmc.usda"
    functions = TaskFunctions(observe=observe, reward_and_end=reward_and_end, sample_reset=sample_reset,
                              joint_forces=joint_forces)


def hold_still_settings(cfg):
    cfg.env.task.episode_length_s, cfg.agent.max_iterations = 1.0, 2


HOLD_STILL = tasks.Task(name="test-hold-still", env_class=HoldStillEnv, summary="hold the cart at the centre",
                        solved=tasks.SolvedRule(min_reward_per_step=0.5), play_metric="mean_reward_per_step",
                        settings=tasks.TaskSettings(common=hold_still_settings),
                        gym_ids={"cartpole_warp/TestHoldStill-v0": None})


@pytest.fixture
def hold_still(monkeypatch):
    """The third task registered for one test (the registry is restored after it)."""
    monkeypatch.setitem(tasks._TASKS, HOLD_STILL.name, HOLD_STILL)
    yield HOLD_STILL.name
    gym.registry.pop("cartpole_warp/TestHoldStill-v0", None)


def test_a_task_from_outside_the_package_builds_trains_plays_and_reaches_gymnasium(hold_still):
    assert hold_still in tasks.names()
    env = tasks.make(hold_still, num_envs=64, seed=0)
    obs, _ = env.reset()
    assert obs.shape == (64, 3) and torch.allclose(obs[:, 1:], torch.zeros(64, 2))
    assert env.max_episode_length == 60
    assert env.end_reasons == ("running", "time_limit", "nonfinite_state", "diverged_state")

    cfg = train_config(hold_still)
    cfg.env.num_envs = 64
    assert cfg.experiment == hold_still and cfg.agent.max_iterations == 2
    runner = TrainingLoop(RslRlVecEnv(tasks.get(hold_still).env_class(cfg.env)), cfg.validate(), None)
    runner.learn(2)
    assert runner.records[0].progress.iterations == 2
    stats = rollout(env, runner.records[0].policy(), steps=60)
    assert stats.episodes == 64 and stats.time_limit_fraction == 1.0
    assert 0.0 < stats.mean_reward_per_step <= 1.0 and math.isfinite(stats.mean_return)

    register_envs()
    single = gym.make("cartpole_warp/TestHoldStill-v0")
    assert single.observation_space.shape == (3,) and single.action_space.shape == (1,)
    obs, _ = single.reset(seed=1)
    assert obs.shape == (3,)
    single.close()


def test_a_misspelt_play_metric_fails_at_registration():
    balance = tasks.get("cartpole-balance")
    with pytest.raises(ValueError, match="play_metric 'time_limit_fractoin' is not one of mean_return, "):
        tasks.register(tasks.Task(name="misspelt", env_class=balance.env_class, solved=balance.solved,
                                  play_metric="time_limit_fractoin", summary="a typo"))
    assert "misspelt" not in tasks.names()


@pytest.mark.parametrize("module, old, new", [
    ("cartpole_warp", "CartpoleGymEnv", "TaskGymEnv"), ("cartpole_warp", "CartpoleVectorEnv", "TaskVectorEnv"),
    ("cartpole_warp.wrappers.gymnasium", "CartpoleGymEnv", "TaskGymEnv"),
    ("cartpole_warp.rl.loop", "TaskRunner", "TrainingLoop"),
    ("cartpole_warp.rl.learners.batched_ppo.learner", "PopulationLearner", "BatchedPpoLearner"),
])
def test_the_old_names_still_work_and_say_the_new_one(module, old, new):
    import importlib

    loaded = importlib.import_module(module)
    with pytest.warns(DeprecationWarning, match=f"{module}.{old} is now {new}"):
        assert getattr(loaded, old) is getattr(loaded, new)
    with pytest.raises(AttributeError, match="has no attribute 'CartpoleMoonwalk'"):
        loaded.CartpoleMoonwalk  # noqa: B018


def test_a_task_module_with_a_misspelt_default_fails_at_import_naming_the_task_and_the_key(tmp_path, monkeypatch):
    (tmp_path / "typo_task.py").write_text(
        "import dataclasses\n"
        "from cartpole_warp import tasks\n"
        "tasks.register(dataclasses.replace(tasks.get('cartpole-balance'), name='typo-balance', gym_ids={},\n"
        "    defaults={'agent': {'algorithm': {'entropy_coeff': 0.01}},\n"
        "              'env': {'task': {'reset_pole_angel_rad': 0.1}, 'sim': {'decimation': 0}}}))\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ConfigError) as raised:
        importlib.import_module("typo_task")
    message = str(raised.value)
    assert message.startswith("task 'typo-balance': defaults")
    assert "unknown config key 'agent.algorithm.entropy_coeff'" in message
    assert "unknown config key 'env.task.reset_pole_angel_rad'" in message
    assert "env.sim.decimation: " in message
    assert "typo-balance" not in tasks.names()


@pytest.mark.parametrize("gpu_defaults, error", [
    ({"agent": {"algorithm": {"num_mini_batch": 4}}}, "unknown config key 'agent.algorithm.num_mini_batch'"),
    ({"env": {"num_envs": 8}}, "env settings do not depend on the device"),
])
def test_a_tasks_gpu_settings_are_checked_when_it_registers(gpu_defaults, error):
    swingup = tasks.get("cartpole-swingup")
    with pytest.raises(ConfigError, match=f"task 'gpu-typo': gpu_defaults.*{error}"):
        tasks.register(dataclasses.replace(swingup, name="gpu-typo", gym_ids={}, gpu_defaults=gpu_defaults))
    assert "gpu-typo" not in tasks.names()


def test_a_tasks_typed_settings_are_checked_when_it_registers():
    """A settings function that sets a field the config has not, a value its type refuses, or (a device's part) an env
    setting is refused as the task registers, each named; the task is not registered."""
    swingup = tasks.get("cartpole-swingup")

    def misspelt(cfg):
        cfg.agent.algorithm.entropy_coeff, cfg.env.task.reset_pole_angel_rad, cfg.env.sim.decimation = 0.01, 0.1, 0

    def env_on_gpu(cfg):
        cfg.env.num_envs = 8

    with pytest.raises(ConfigError) as raised:
        tasks.register(dataclasses.replace(swingup, name="typed-typo", gym_ids={},
                                           settings=tasks.TaskSettings(common=misspelt)))
    message = str(raised.value)
    assert message.startswith("task 'typed-typo': settings.common")
    assert "unknown config key 'agent.algorithm.entropy_coeff'" in message
    assert "unknown config key 'env.task.reset_pole_angel_rad'" in message and "env.sim.decimation: " in message
    with pytest.raises(ConfigError, match="'typed-gpu': settings.on_gpu: env settings do not depend on the device"):
        tasks.register(dataclasses.replace(swingup, name="typed-gpu", gym_ids={},
                                           settings=tasks.TaskSettings(on_gpu=env_on_gpu)))
    assert "typed-typo" not in tasks.names() and "typed-gpu" not in tasks.names()


def test_a_task_declared_with_the_dicts_of_before_resolves_as_its_typed_twin(monkeypatch):
    """The swing-up's settings written as the nested dicts tasks gave before ``TaskSettings`` (with a warning, until
    0.2.0) resolve to the same config as its typed settings, on each device and with each learner."""
    monkeypatch.setattr(tasks, "_TASKS", dict(tasks._TASKS))
    swingup = tasks.get("cartpole-swingup")
    with pytest.warns(DeprecationWarning, match="is now Task\\(settings=TaskSettings"):
        tasks.register(dataclasses.replace(
            swingup, name="dict-swingup", gym_ids={}, settings=tasks.TaskSettings(),
            defaults={"env": {"sim": {"physics_dt": 0.01, "decimation": 2}},
                      "agent": {"max_iterations": 500, "num_steps_per_env": 16,
                                "algorithm": {"entropy_coef": 0.02, "symmetry": False, "num_learning_epochs": 2},
                                "actor": {"obs_normalization": True}, "critic": {"obs_normalization": True}}},
            gpu_defaults={"agent": {"algorithm": {"num_mini_batches": 4}}, "eval": {"max_interval": 50}},
            cpu_defaults={"agent": {"actor": {"hidden_dims": [16, 16]}, "critic": {"hidden_dims": [16, 16]}}},
            learner_defaults={"shac": {"agent": {"max_iterations": 1100, "actor": {"hidden_dims": [64, 64]},
                                                 "critic": {"hidden_dims": [64, 64]}}}}))
    for device in ("cpu", "cuda"):
        for learner in (None, "shac", "sapg"):
            typed = dataclasses.asdict(train_config(swingup.name, device=device, learner=learner))
            dicts = dataclasses.asdict(train_config("dict-swingup", device=device, learner=learner))
            assert dicts == typed | {"task": "dict-swingup"}, (device, learner)
