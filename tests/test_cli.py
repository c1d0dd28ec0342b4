"""Command-line glue (``cli.py``): the programs' short flags, which the config classes do not know."""

import dataclasses
import typing

import pytest

from cartpole_warp import play, train
from cartpole_warp.cli import ENV_ALIASES, expand_aliases
from cartpole_warp.settings.agent import RunnerConfig
from cartpole_warp.settings.config import EnvConfig


def test_short_flags_are_written_as_the_fields_own_flags_in_every_form():
    argv = ["--num-envs", "8", "--device=cpu", "--seed_x", "--num_envs=16", "--task", "--seed", "--", "--seed"]
    assert expand_aliases(argv, ENV_ALIASES) == [
        "--env.num-envs", "8", "--env.device=cpu", "--seed_x", "--env.num-envs=16", "--task", "--env.seed", "--",
        "--env.seed"]


@pytest.mark.parametrize("config_class", [EnvConfig, RunnerConfig])
def test_the_config_classes_name_no_programs_flag(config_class):
    hints = typing.get_type_hints(config_class, include_extras=True)
    for field in dataclasses.fields(config_class):
        markers = getattr(hints[field.name], "__metadata__", ())
        assert not any(getattr(marker, "aliases", None) for marker in markers), f"{field.name} carries a CLI alias"


def test_train_and_play_take_the_short_flags_as_the_long_ones(tmp_path):
    short = ["--num-envs", "8", "--device", "cpu", "--seed", "3"]
    long = ["--env.num-envs", "8", "--env.device", "cpu", "--env.seed", "3"]
    runs = ["--max-iterations", "2", "--run-name", "x", "--logger", "none", "--log-dir", str(tmp_path)]
    cfg, run_dir, _ = train.resolve(short + runs)
    assert (cfg.env.num_envs, cfg.env.device, cfg.env.seed) == (8, "cpu", 3)
    assert (cfg.agent.max_iterations, cfg.agent.run_name, cfg.agent.logger) == (2, "x", "none")
    assert run_dir.name.endswith("_x")
    assert train.resolve(long + ["--agent.max-iterations", "2", "--log-dir", str(tmp_path)])[0].env == cfg.env
    played = [play.resolve(flags + ["--agent", "zero", "--headless"])[1].env for flags in (short, long)]
    assert played[0] == played[1] and played[0].num_envs == 8 and played[0].seed == 3
