"""The package's folders are its layers: the modules moved out of the root still import from their old paths for a
release (the same module, with a DeprecationWarning naming the new path), and the root keeps the programs and the
package's face."""

import importlib
import sys
import warnings
from pathlib import Path

import pytest

import cartpole_warp
from cartpole_warp.cli import renamed_flags

OLD_PATHS = {  # the root modules of 56e07f5 -> their folders
    "env": "engine.env", "kernels": "engine.kernels", "camera": "engine.camera",
    "randomization": "engine.randomization", "scene": "engine.scene", "runtime": "engine.runtime",
    "streams": "engine.streams", "config": "settings.config",
    "agent": "settings.agent", "presets": "settings.presets", "files": "settings.files",
    "deprecation": "settings.deprecation", "statistics": "evaluation.statistics", "robustness": "evaluation.robustness",
    "tasks.cartpole": "tasks.cart_base",  # the cart tasks' shared parts, named like a task before
    "rl.learner": "rl.learners", "rl.ppo_learner": "rl.learners.ppo.learner", "rl.ppo": "rl.learners.ppo.sync_free",
    "rl.population_ppo": "rl.learners.batched_ppo.update", "rl.sapg": "rl.learners.sapg.learner",
    "rl.apg": "rl.learners.shac.learner",  # the learners before their wing
}


@pytest.mark.parametrize("old, new", OLD_PATHS.items())
def test_an_old_module_path_imports_the_moved_module_and_says_where_it_went(monkeypatch, old, new):
    monkeypatch.delitem(sys.modules, f"cartpole_warp.{old}", raising=False)
    with pytest.warns(DeprecationWarning, match=f"module cartpole_warp.{old} is now cartpole_warp.{new}"):
        loaded = importlib.import_module(f"cartpole_warp.{old}")
    moved = importlib.import_module(f"cartpole_warp.{new}")
    assert loaded is moved
    assert moved.__spec__.name == moved.__name__ == f"cartpole_warp.{new}"


def test_the_old_evaluation_module_names_answer_from_the_rollouts_module(monkeypatch):
    from cartpole_warp.evaluation import rollouts

    package = importlib.import_module("cartpole_warp.evaluation")
    monkeypatch.delitem(vars(package), "first_episodes", raising=False)
    with pytest.warns(DeprecationWarning, match="evaluation.first_episodes is now cartpole_warp.evaluation.rollouts"):
        assert package.first_episodes is rollouts.first_episodes
    with pytest.raises(AttributeError, match="has no attribute 'moonwalk'"):
        package.moonwalk  # noqa: B018


def test_the_root_holds_the_programs_and_the_face():
    root = Path(cartpole_warp.__file__).parent
    modules = sorted(p.stem for p in root.glob("*.py"))
    assert modules == ["__init__", "cli", "play", "train", "warmup"]
    assert {p.name for p in root.iterdir() if (p / "__init__.py").exists()} == {
        "engine", "evaluation", "gradients", "identification", "rl", "settings", "tasks", "tools", "viz", "wrappers"}


@pytest.mark.parametrize("old, new, name", [
    *[("rl.runner", "rl.policies", name) for name in ("load_policy", "NullLogWriter")],
    *[("rl.population", "rl.learners.batched_ppo.learner", name) for name in ("PopulationLearner", "Member")],
    *[("tools.sysid", "identification.sysid", name) for name in ("fit", "SysidArgs", "read_problem")],
    ("rl.learners.ppo.sync_free", "rl.policies", "SyncFreeGaussian"),
])
def test_a_name_that_left_its_module_answers_there_from_its_new_one(monkeypatch, old, new, name):
    """The policy functions that left the runner, the batched learner's parts that left rl.population, the sysid
    library that left its program, the Gaussian that left the sync-free update."""
    left = importlib.import_module(f"cartpole_warp.{old}")
    moved = importlib.import_module(f"cartpole_warp.{new}")
    monkeypatch.delitem(vars(left), name, raising=False)  # a name an earlier lookup cached
    with pytest.warns(DeprecationWarning, match=f"{old}.{name} is now cartpole_warp.{new}.{name}"):
        assert getattr(left, name) is getattr(moved, name)


def test_the_gymnasium_envs_old_core_attribute_is_their_env():
    from cartpole_warp.wrappers.gymnasium import TaskGymEnv, TaskVectorEnv

    for env in (TaskGymEnv(), TaskVectorEnv(num_envs=2)):
        with pytest.warns(DeprecationWarning, match=r"\.core is now \.env"):
            assert env.core is env.env
        env.close()


def test_a_task_written_with_the_old_evaluate_name_gets_its_reward_and_end():
    import dataclasses

    from cartpole_warp.engine.kernels import TaskFunctions
    from cartpole_warp.tasks import balance, balance_sparse

    functions = balance.CartpoleBalanceEnv.functions
    message = r"TaskFunctions\(evaluate=\.\.\.\) is now TaskFunctions\(reward_and_end="
    with pytest.warns(DeprecationWarning, match=message):
        old = dataclasses.replace(functions, evaluate=balance_sparse.reward_and_end)
    assert old == balance_sparse.CartpoleBalanceSparseEnv.functions
    with pytest.warns(DeprecationWarning):
        assert TaskFunctions(functions.observe, evaluate=functions.reward_and_end, sample_reset=functions.sample_reset,
                             joint_forces=functions.joint_forces) == functions
    with pytest.raises(TypeError, match="TaskFunctions: missing reward_and_end"):
        TaskFunctions(functions.observe, sample_reset=functions.sample_reset, joint_forces=functions.joint_forces)


@pytest.mark.parametrize("module, old, new", [
    ("evaluation.rollouts", "NO_LIMIT_STEPS", "STEPS_WITHOUT_TIME_LIMIT"),
    ("engine.randomization", "Physics", "PhysicalParams"), ("engine.streams", "TorchOrder", "StreamOrder"),
    ("engine.kernels", "kernel_params", "kernel_constants"), ("engine.kernels", "params_of", "constants_of"),
    ("rl.learners.shac.learner", "ApgLearner", "ShacLearner"), ("rl.learners.shac.learner", "check_apg", "check_shac"),
    ("rl.learners.shac.learner", "ADAM_BETAS", "SHAC_ADAM_BETAS"),
    ("rl.learners.batched_ppo.update", "ADAM_BETAS", "PPO_ADAM_BETAS"),
    ("rl.learners.batched_ppo.update", "ADAM_EPS", "PPO_ADAM_EPS"), ("settings.agent", "ApgConfig", "ShacConfig"),
])
def test_the_renamed_engine_and_evaluation_names_answer_for_a_release(module, old, new):
    loaded = importlib.import_module(f"cartpole_warp.{module}")
    with pytest.warns(DeprecationWarning, match=f"{module}.{old} is now {new}"):
        assert getattr(loaded, old) is getattr(loaded, new)


def test_the_old_names_go_in_the_release_they_name(tmp_path, capsys):
    """Every alias answered for a release says which one drops it (``REMOVED_IN``); once the package's version reaches
    it this test fails: delete the aliases (``renamed``, ``renamed_attribute``, ``moved_names``, ``MOVED_MODULES``, the
    ``evaluate=`` keyword) and this test."""
    import tomllib
    from packaging.version import Version

    from cartpole_warp.settings.deprecation import REMOVED_IN

    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    assert Version(tomllib.loads(pyproject.read_text())["project"]["version"]) < Version(REMOVED_IN)
    with pytest.warns(DeprecationWarning, match=f"the old name goes in {REMOVED_IN}"):
        assert importlib.import_module("cartpole_warp.rl.runner").CartpoleRunner.__name__ == "TrainingLoop"
    from cartpole_warp.play import GRID_ALIASES
    from cartpole_warp.train import RENAMED_FLAGS, resolve

    for old, new in RENAMED_FLAGS.items() | GRID_ALIASES.items():
        assert renamed_flags([old, "x"], RENAMED_FLAGS | GRID_ALIASES) == [new, "x"]
        assert f"note: {old} is now {new}; the old spelling goes in {REMOVED_IN}\n" == capsys.readouterr().err
    cfg, _, _ = resolve(["--algorithm=apg", "--log-dir", str(tmp_path)])
    err = capsys.readouterr().err
    assert cfg.agent.learner == "shac" and "--algorithm is now --learner" in err
    assert f"note: --learner apg is now --learner shac; the old spelling goes in {REMOVED_IN}" in err


def test_the_learner_once_called_apg_is_shac_by_its_old_name_its_old_flags_and_in_an_old_runs_config(tmp_path,
                                                                                                     capsys):
    """``--learner apg`` named SHAC (a critic; Brax's APG has none): the old name, its section's flags and a config.yaml
    written with them still give the same run, until ``REMOVED_IN``."""
    import yaml

    from cartpole_warp.rl.config import load_train_config
    from cartpole_warp.train import resolve

    old, _, _ = resolve(["--agent.learner", "apg", "--agent.apg.gamma", "0.98", "--log-dir", str(tmp_path)])
    new, _, _ = resolve(["--learner", "shac", "--agent.shac.gamma", "0.98", "--log-dir", str(tmp_path)])
    assert old == new and new.agent.learner == "shac" and new.agent.shac.gamma == 0.98
    err = capsys.readouterr().err
    assert "note: --agent.learner apg is now --agent.learner shac" in err
    assert "note: --agent.apg.gamma is now --agent.shac.gamma" in err
    saved = yaml.safe_load(yaml.safe_dump(
        {"task": "cartpole-balance", "agent": {"learner": "apg", "apg": {"gamma": 0.98}}}))
    with pytest.warns(FutureWarning, match="config.yaml: learner 'apg' is now 'shac'"):
        loaded = load_train_config(saved, "config.yaml").agent
    assert loaded.learner == "shac" and loaded.shac == new.agent.shac
    preset = tmp_path / "old.yaml"
    preset.write_text(yaml.safe_dump(saved))
    with pytest.warns(FutureWarning, match="old.yaml: learner 'apg' is now 'shac'"):
        from_preset, _, _ = resolve(["--config", str(preset), "--log-dir", str(tmp_path)])
    assert from_preset.agent.learner == "shac" and from_preset.agent.shac.gamma == 0.98
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a PPO run's config.yaml of those releases: its apg section, silently
        ppo = load_train_config({"task": "cartpole-balance", "agent": {"apg": {"gamma": 0.98}}}, "config.yaml")
    assert ppo.agent.learner == "ppo" and ppo.agent.shac.gamma == 0.98


def test_a_task_naming_a_learner_by_its_old_name_gets_it_and_one_naming_no_learner_is_refused(monkeypatch):
    """``Task.learner_defaults`` keyed ``apg`` (the learner's name before ``shac``) still applies, with a warning,
    until ``REMOVED_IN``; a key that names no learner is refused when the task registers, not ignored."""
    import dataclasses

    from cartpole_warp import tasks
    from cartpole_warp.rl.config import train_config
    from cartpole_warp.settings.config import ConfigError

    monkeypatch.setattr(tasks, "_TASKS", dict(tasks._TASKS))
    base = tasks.get("cartpole-balance")
    old = dataclasses.replace(base, name="an-old-task", learner_defaults={"apg": {"agent": {"max_iterations": 7}}})
    with pytest.warns(DeprecationWarning, match=r"learner_defaults\['apg'\] is now \['shac'\]"):
        registered = tasks.register(old)
    assert set(registered.settings.for_learner) == {"shac"}
    assert train_config("an-old-task", learner="shac").agent.max_iterations == 7
    assert tasks.get("an-old-task") is registered
    with pytest.raises(ConfigError, match="learner_defaults names 'sac', no learner"):
        tasks.register(dataclasses.replace(base, name="a-typo-task", learner_defaults={"sac": {}}))
