"""Training configs (``rl/config.py``, ``presets.py``, ``agent.py``): precedence of defaults, presets and flags,
bad presets, the checks that relate fields, every field in ``--help-all``, the rsl-rl ``train_cfg`` it makes."""

import ast
import contextlib
import dataclasses
import inspect
import io

import pytest
from rsl_rl.utils import resolve_callable

from cartpole_warp import tasks
from cartpole_warp.rl.config import RunnerConfig, device_settings, gpu_settings, train_config
from cartpole_warp.rl.policies import to_rsl_rl
from cartpole_warp.settings.config import ConfigError
from cartpole_warp.settings.presets import load_preset, presets
from cartpole_warp.train import resolve
from cartpole_warp.wrappers.rsl_rl import mirror


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
    for klass in reversed([k for k in cls.__mro__ if k.__module__.startswith("cartpole_warp")]):  # not typing.Generic
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


@pytest.mark.parametrize("preset", presets())
def test_every_shipped_preset_applies_to_its_task_and_is_refused_by_the_others(preset):
    task = load_preset(preset).get("task")
    assert task is None or task in tasks.names(), f"{preset} names a registered task"
    for name in tasks.names():
        if task in (None, name):
            assert train_config(name, preset).validate().task == name
        else:
            with pytest.raises(ConfigError, match=f"preset {preset!r} is for task {task!r}, not {name!r}"):
                train_config(name, preset)


def test_the_swingups_gpu_and_cpu_configs_differ_only_in_their_device_settings():
    default, gpu = train_config("cartpole-swingup"), train_config("cartpole-swingup", device="cuda:0")
    assert (gpu.agent.algorithm.num_mini_batches, gpu.eval.max_interval) == (4, 50)
    assert (default.agent.algorithm.num_mini_batches, default.eval.max_interval) == (8, 25)
    assert gpu.env.device == "cuda:0" and gpu_settings(gpu) == {"agent.algorithm.num_mini_batches": 4,
                                                                 "eval.max_interval": 50}
    changed = dataclasses.replace(gpu, agent=dataclasses.replace(
        gpu.agent, algorithm=dataclasses.replace(gpu.agent.algorithm, num_mini_batches=8),
        actor=dataclasses.replace(gpu.agent.actor, hidden_dims=[16, 16]),
        critic=dataclasses.replace(gpu.agent.critic, hidden_dims=[16, 16])),
        eval=dataclasses.replace(gpu.eval, max_interval=25), env=dataclasses.replace(gpu.env, device="cpu"))
    assert changed == default, "every other setting is the swing-up's"
    assert train_config("cartpole-swingup", device="cpu") == default
    assert gpu_settings(default) == {}
    assert device_settings(default) == {"agent.actor.hidden_dims": [16, 16], "agent.critic.hidden_dims": [16, 16]}
    for variant in ("cartpole-swingup-sparse", "cart-two-pole-swingup"):  # not measured with them
        assert device_settings(train_config(variant)) == {}, variant
    assert train_config("cartpole-swingup", learner="shac").agent.actor.hidden_dims == [64, 64], "SHAC's own"
    assert train_config("cartpole-balance", learner="shac").agent.actor.hidden_dims == [32, 32], "as measured"


def test_on_a_cpu_the_balance_takes_narrow_networks_and_a_gpu_or_a_flag_keeps_the_wide_ones(tmp_path):
    cpu, gpu = train_config("cartpole-balance"), train_config("cartpole-balance", device="cuda:0")
    assert (cpu.agent.actor.hidden_dims, cpu.agent.critic.hidden_dims) == ([8, 8], [8, 8])
    assert (gpu.agent.actor.hidden_dims, gpu.agent.critic.hidden_dims) == ([32, 32], [32, 32])
    assert device_settings(cpu) == {"agent.actor.hidden_dims": [8, 8], "agent.critic.hidden_dims": [8, 8]}
    assert device_settings(gpu) == gpu_settings(gpu) == gpu_settings(cpu) == {}
    assert train_config("cartpole-balance", "isaac_lab").agent.actor.hidden_dims == [32, 32], "Isaac Lab's own"
    for variant in ("cartpole-balance-sparse", "cartpole-balance-rgb"):  # not measured with them
        assert device_settings(train_config(variant)) == {}, variant
    cfg, _, _ = resolve(["--log-dir", str(tmp_path), "--agent.actor.hidden-dims", "32", "32"])
    assert device_settings(cfg) == {"agent.actor.hidden_dims": [32, 32], "agent.critic.hidden_dims": [8, 8]}


def test_train_takes_the_gpu_settings_from_the_device_flag_and_a_flag_still_changes_them(tmp_path):
    for device_flag in (["--device", "cuda:0"], ["--env.device=cuda"]):
        cfg, _, _ = resolve(["--task", "cartpole-swingup", *device_flag, "--log-dir", str(tmp_path)])
        assert gpu_settings(cfg) == {"agent.algorithm.num_mini_batches": 4, "eval.max_interval": 50}, device_flag
    cfg, _, _ = resolve(["--task", "cartpole-swingup", "--device", "cuda", "--log-dir", str(tmp_path),
                         "--agent.algorithm.num-mini-batches", "2"])
    assert gpu_settings(cfg) == {"agent.algorithm.num_mini_batches": 2, "eval.max_interval": 50}
    for cpu in ([], ["--device", "cuda", "--env.device", "cpu"]):  # the last of the two spellings counts, as in tyro
        cfg, _, _ = resolve(["--task", "cartpole-swingup", "--log-dir", str(tmp_path), *cpu])
        assert cfg.env.device == "cpu" and (cfg.agent.algorithm.num_mini_batches, cfg.eval.max_interval) == (8, 25)


def test_the_retired_gpu_preset_says_where_its_settings_went():
    with pytest.raises(ConfigError, match="preset 'swingup_gpu' is retired: a task's settings for a GPU come with"):
        train_config("cartpole-swingup", "swingup_gpu")


def test_runner_config_is_rsl_rl_train_cfg():
    cfg = to_rsl_rl(RunnerConfig())
    from cartpole_warp.rl.learners.ppo.sync_free import SyncFreePPO
    from cartpole_warp.rl.policies import SyncFreeGaussian

    assert resolve_callable(cfg["algorithm"]["class_name"]) is SyncFreePPO
    assert cfg["algorithm"]["entropy_coef"] == 0.005
    assert cfg["actor"]["class_name"] == cfg["critic"]["class_name"] == "MLPModel"
    distribution = cfg["actor"]["distribution_cfg"]
    assert cfg["actor"]["hidden_dims"] == [32, 32] and distribution["init_std"] == 1.0 and len(distribution) == 2
    assert resolve_callable(distribution["class_name"]) is SyncFreeGaussian
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


def test_a_run_reads_its_preset_file_once(tmp_path, monkeypatch):
    import yaml

    preset = tmp_path / "p.yaml"
    preset.write_text("env:\n  num_envs: 64\nagent:\n  max_iterations: 7\n")
    reads = []
    safe_load = yaml.safe_load
    monkeypatch.setattr(yaml, "safe_load", lambda text: reads.append(text) or safe_load(text))
    resolve(["--config", str(preset), "--log-dir", str(tmp_path)])
    assert len(reads) == 1, "one read, its env section and the rest taken from it"
