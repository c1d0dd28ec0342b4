"""The sweep (``tools/sweep.py``): variants as train.py flags, failed runs unsolved, a seed repeated exactly in one
process."""

import json

import pytest
import torch

from cartpole_warp.train import resolve


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


@pytest.mark.parametrize("variant, option", [("num-envs=16384", "--num-envs"),
                                             ("agent.max-iterations=5", "--max-iterations"),
                                             ("env.seed=3 agent.algorithm.gamma=0.995", "--seeds")])
def test_a_variant_that_sets_a_flag_the_sweep_sets_is_refused_with_the_sweeps_option(variant, option, capsys):
    from cartpole_warp.tools.sweep import main

    with pytest.raises(SystemExit) as stop:
        main(["--variants", variant, "--seeds", "0", "--num-envs", "64", "--max-iterations", "3"])
    assert stop.value.code == 2
    error = capsys.readouterr().err
    assert "is set by the sweep for every run" in error and option in error


def test_a_variant_of_other_flags_runs_with_its_own_defaults(tmp_path, capsys):
    """A variant's flags that the sweep does not set pass (whatever their order), and without --num-envs each run
    takes its own env count: here ``--learner shac``'s."""
    from cartpole_warp.settings.agent import LEARNER_DEFAULTS
    from cartpole_warp.tools.sweep import main

    assert main(["--variants", "learner=shac agent.shac.gamma=0.98", "--seeds", "0", "--max-iterations", "2",
                 "--no-stop-when-solved", "--log-dir", str(tmp_path)]) == 0
    assert "| `--learner shac --agent.shac.gamma 0.98` | 0 | not solved |" in capsys.readouterr().out
    summary = json.loads(next(tmp_path.rglob("summary.json")).read_text())
    assert summary["num_envs"] == LEARNER_DEFAULTS["shac"]["env"]["num_envs"]


def test_a_sweep_trains_its_seeds_as_a_population_and_says_when_a_variant_cannot(tmp_path, capsys):
    """--population: the seeds of a variant as one population, a row per member from its own run folder (played), and
    a variant that cannot train as a population (--learner shac) runs its seeds one by one, saying why."""
    from cartpole_warp.tools.sweep import main

    assert main(["--seeds", "1", "2", "--num-envs", "16", "--max-iterations", "2", "--play", "--population",
                 "--variants", "", "agent.learner=shac", "--log-dir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "population of (default): 2 members trained together in" in out
    assert "`--agent.learner shac` cannot train as a population (a population of cartpole-balance cannot train with " \
           "--learner shac (populations train with PPO)): its seeds run one by one" in out
    rows = [line for line in out.splitlines() if line.startswith(("| (default) | 1 |", "| (default) | 2 |"))]
    assert len(rows) == 2
    assert all(row.split("|")[-2].strip() != "-" for row in rows), "each member was played"
    assert len(list(tmp_path.glob("v0_population/**/population.json"))) == 1
    assert len(list(tmp_path.glob("v1_s*/**/summary.json"))) == 2
