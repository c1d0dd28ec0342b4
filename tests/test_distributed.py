"""Multi-GPU training without GPUs: which device and seed each torchrun process takes, that only rank 0 writes, the
joint stop decision and the summed statistics (real all-reduces over two CPU processes with gloo), the errors."""

import os
import subprocess
import sys

import pytest
import torch
import torch.distributed
import torch.multiprocessing

from cartpole_warp import tasks
from cartpole_warp.evaluation.statistics import EpisodeStats
from cartpole_warp.rl.config import train_config
from cartpole_warp.rl.distributed import Ranks, joint_stop
from cartpole_warp.rl.training import Training
from cartpole_warp.settings.config import ConfigError


def test_ranks_come_from_torchrun_variables():
    assert Ranks.from_environment({}) == Ranks(1, 0, 0) and not Ranks().distributed and Ranks().writes
    ranks = Ranks.from_environment({"WORLD_SIZE": "4", "RANK": "3", "LOCAL_RANK": "1"})
    assert ranks == Ranks(4, 3, 1) and ranks.distributed and not ranks.writes
    with pytest.raises(ConfigError, match="must be integers"):
        Ranks.from_environment({"WORLD_SIZE": "two"})


@pytest.mark.parametrize("task", tasks.names())
def test_each_process_takes_its_gpu_and_seed_plus_rank_and_keeps_every_other_setting(task):
    env = tasks.env_config(task, num_envs=4096, device="cuda", seed=7, sim={"solver": "mujoco", "cpu_threads": 1},
                           task={"episode_length_s": 3.0})
    mine = Ranks(4, 3, 1).env_config(env, cuda_devices=2)
    assert (mine.device, mine.seed, mine.num_envs) == ("cuda:1", 10, 4096)
    assert (mine.sim, mine.task) == (env.sim, env.task) and type(mine.task) is type(env.task)
    assert Ranks(2, 0, 0).env_config(env, cuda_devices=2).seed == 7
    assert Ranks().env_config(env, cuda_devices=0) is env, "one process keeps its config"
    with pytest.raises(ConfigError, match="needs --device cuda"):
        Ranks(2, 0, 0).env_config(tasks.env_config(task, device="cpu"), cuda_devices=2)
    with pytest.raises(ConfigError, match="host has 2 CUDA device"):
        Ranks(4, 2, 2).env_config(env, cuda_devices=2)


def test_a_populations_members_are_shared_out_in_order_and_each_process_takes_its_gpu():
    members = list("abcde")
    assert [Ranks(2, rank, rank).share(members) for rank in (0, 1)] == [["a", "b"], ["c", "d", "e"]]
    assert [Ranks(5, rank, 0).share(members) for rank in range(5)] == [[m] for m in members]
    assert Ranks().share(members) == members
    with pytest.raises(ConfigError, match="5 members cannot be spread over 6 processes"):
        Ranks(6, 0, 0).share(members)
    assert Ranks(2, 1, 1).device("cuda", cuda_devices=2) == "cuda:1" and Ranks(2, 1, 1).device("cpu", 0) == "cpu"
    assert Ranks().device("cuda:3", cuda_devices=4) == "cuda:3"
    with pytest.raises(ConfigError, match="host has 1 CUDA device"):
        Ranks(2, 1, 1).device("cuda", cuda_devices=1)


@pytest.mark.parametrize("wanted", [None, "solved", "interrupted"])
def test_a_process_alone_stops_as_it_wishes(wanted):
    assert joint_stop(wanted, "cpu", distributed=False) == wanted


def _two_processes(rank, store, results):
    torch.distributed.init_process_group("gloo", init_method=f"file://{store}", rank=rank, world_size=2)
    stats = EpisodeStats("cpu", max_episode_length=30)
    ended = torch.tensor([True, rank == 1])
    stats.add(ended, torch.tensor([10.0 * (rank + 1), 30.0]), torch.tensor([10, 30]), torch.tensor([False, True]))
    summary = stats.pop(all_processes=True)
    interrupted = joint_stop("interrupted" if rank == 1 else None, "cpu", True)
    solved = joint_stop("solved" if rank == 0 else None, "cpu", True)
    strongest = joint_stop("solved" if rank == 0 else "interrupted", "cpu", True)
    results[rank] = (summary.episodes, summary.mean_return, (interrupted, solved, strongest), summary.full_episodes)
    torch.distributed.destroy_process_group()


def test_statistics_and_stop_are_reduced_over_processes(tmp_path):
    results = torch.multiprocessing.Manager().dict()
    torch.multiprocessing.spawn(_two_processes, args=(str(tmp_path / "store"), results), nprocs=2)
    # rank 0 ended one episode (return 10), rank 1 two (returns 20 and 30, the second full): 3 episodes, mean 20
    assert results[0] == results[1] == (3, 20.0, ("interrupted", "solved", "interrupted"), 1)


def test_more_processes_than_gpus_are_refused_naming_the_count():
    env = train_config().env
    env.device = "cuda"
    with pytest.raises(ConfigError, match="process 2 of this host needs cuda:2, but the host has 2 CUDA device"):
        Ranks(world_size=4, rank=2, local_rank=2).env_config(env, cuda_devices=2)
    assert Ranks(world_size=4, rank=1, local_rank=1).env_config(env, cuda_devices=2).device == "cuda:1"


def test_only_rank_zero_writes_the_run(tmp_path):
    cfg = train_config()
    cfg.env.num_envs, cfg.agent.max_iterations = 64, 1
    run_dir = tmp_path / "run"
    summary = Training(cfg, run_dir, ranks=Ranks(world_size=1, rank=1)).run()
    assert summary is None and not run_dir.exists()
    assert Training(cfg, run_dir).run().iterations == 1 and (run_dir / "summary.json").is_file()


@pytest.mark.parametrize("variables, flags, message", [
    ({"WORLD_SIZE": "2", "RANK": "0", "LOCAL_RANK": "0"}, ["--device", "cpu"], "needs --device cuda"),
    ({"WORLD_SIZE": "16", "RANK": "15", "LOCAL_RANK": "15", "CUDA_VISIBLE_DEVICES": ""}, ["--device", "cuda"],
     "torch sees no GPU on this host"),  # no GPU visible: on a GPU host too
])
def test_torchrun_errors_are_one_line(repo, tmp_path, variables, flags, message):
    result = subprocess.run([sys.executable, str(repo / "train.py"), "--num-envs", "64", "--log-dir", str(tmp_path),
                             *flags], env={**os.environ, **variables}, capture_output=True, text=True, timeout=300)
    assert result.returncode == 2 and message in result.stderr, result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "rsl_rl").exists()
