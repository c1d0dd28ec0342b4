"""Run folders (``rl/runs.py``): found newest first in their experiment."""


import pytest

from cartpole_warp import tasks
from cartpole_warp.rl.config import train_config
from cartpole_warp.rl.runs import (
    RunError,
    latest_checkpoint,
    latest_run,
    load_config,
    new_run_dir,
    save_config,
)
from cartpole_warp.settings.config import ConfigError


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
