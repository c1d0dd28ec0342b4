"""The training loop (``rl/loop.py``): random episode starts, the phase clock, play's policy, the progress line."""

import re
import time

import pytest
import torch

import cartpole_warp
from cartpole_warp.rl.config import train_config
from cartpole_warp.rl.distributed import SINGLE_PROCESS
from cartpole_warp.rl.learners import learner_class
from cartpole_warp.rl.loop import TrainingLoop
from cartpole_warp.rl.progress import eta_s
from cartpole_warp.rl.runs import (
    RunError,
)
from cartpole_warp.wrappers.rsl_rl import RslRlVecEnv


@pytest.mark.parametrize("spread", [False, True])
def test_random_episode_starts_spread_time_outs_and_report_true_lengths(spread):
    cfg = train_config()
    cfg.env.num_envs, cfg.env.task.episode_length_s, cfg.agent.num_steps_per_env = 64, 0.1, 12
    torch.manual_seed(0)
    env = RslRlVecEnv(cartpole_warp.make_env(num_envs=64, seed=0, task={"episode_length_s": 0.1}))
    runner = TrainingLoop(env, cfg, None)
    runner.learn(1, init_at_random_ep_len=spread)
    first = runner.records[0].progress.history[0]
    assert first["time_limit_fraction"] > 0.95, "a 6-step limit ends nearly every episode by time"
    if spread:
        assert first["mean_episode_length"] < 5.5, "first episodes cut short by their random counters say so"
    else:
        assert first["mean_episode_length"] > 5.8


def test_phase_clock_times_each_phase_on_its_device(device):
    """On the CPU the host clock; on a GPU CUDA events, which time the device's work, not the host's queueing."""
    from cartpole_warp.engine.streams import PhaseClock

    if device.startswith("cuda"):
        matrix = torch.randn(4096, 4096, device=device)

        def work(units):
            for _ in range(units):
                matrix @ matrix

        work(1)  # cuBLAS's first product loads its kernels: seconds that are no phase's work
        torch.cuda.synchronize(device)
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
    from cartpole_warp.rl.policies import load_policy

    cfg = train_config()
    cfg.env.num_envs = 16
    env = RslRlVecEnv(cartpole_warp.make_env(num_envs=16, seed=0))
    torch.manual_seed(0)
    runner = TrainingLoop(env, cfg, None)
    runner.learn(2)
    runner.records[0].save(str(tmp_path / "model.pt"))
    obs = torch.randn(16, env.env.num_obs)
    with torch.inference_mode():
        assert torch.equal(load_policy(env, cfg.agent, tmp_path / "model.pt")(obs), runner.records[0].policy()(obs))
    cfg.agent.actor.hidden_dims = [8]
    with pytest.raises(RunError, match="does not match the configured networks"):
        load_policy(env, cfg.agent, tmp_path / "model.pt")


@pytest.mark.parametrize("learner", ["ppo", "shac"])
def test_an_iteration_in_which_no_episode_ended_says_how_long_they_have_run(capsys, learner):
    """A balancing policy ends no episode for many iterations; its console row says the envs are still running and
    for how long (the learner's count: SHAC steps a rollout of its own, not the env), not only that nothing
    finished."""
    cfg = train_config(learner=learner)
    cfg.env.num_envs, cfg.agent.num_steps_per_env, cfg.agent.init_at_random_ep_len = 16, 2, False
    env_cfg = learner_class(learner).env_config(cfg, cfg.env, SINGLE_PROCESS)
    torch.manual_seed(0)
    runner = TrainingLoop(RslRlVecEnv(cfg.task_spec.env_class(env_cfg)), cfg, None)
    runner.learn(2)
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("it ")]
    dt = cfg.env.sim.env_dt
    assert [row.split(" | ")[1].strip() for row in rows] == [
        f"no episode ended; 16 running, {2 * dt:5.2f} s in on average",
        f"no episode ended; 16 running, {4 * dt:5.2f} s in on average"], rows


def test_the_eta_counts_the_evaluations_measured_so_far():
    """10 iterations took 100 s, of which two evaluations 30 s each: 4 s per iteration; 20 iterations and 3
    evaluations left take 80 + 90 s. Before any evaluation has run there is nothing to count them by."""
    assert eta_s(100.0, [30.0, 30.0], 10, 20, 3) == pytest.approx(170.0)
    assert eta_s(40.0, [], 10, 20, 3) == pytest.approx(80.0)


def test_a_run_that_will_take_hours_says_so_after_its_first_iteration(capsys):
    """A 16-env run asked for 10**7 iterations: its first progress line is followed by the note with the estimate and
    what makes it shorter."""
    cfg = train_config()
    cfg.env.num_envs, cfg.agent.num_steps_per_env = 16, 2
    runner = TrainingLoop(RslRlVecEnv(cartpole_warp.make_env(num_envs=16, seed=0)), cfg, None)
    runner.learn(1)
    assert "note:" not in capsys.readouterr().out, "a short run has nothing to say"
    runner.request_stop()  # after the first iteration
    runner.learn(10**7)
    out = capsys.readouterr().out
    note = out.splitlines()[1]
    assert re.fullmatch(r"note: at this pace the 10000000 iterations of cartpole-balance take about \d+h\d\dm more on "
                        r"cpu \(16 envs\): a GPU \(--device cuda\) is far faster \(docs/results.md: each task's "
                        r"measured times\), or set fewer --max-iterations", note), out


def test_the_runner_is_one_loop_over_learners_found_by_name():
    """The seam: the runner module stays at most 200 lines, nothing subclasses the runner to change the learning, and
    a learner is found by its name alone (train.py --learner NAME)."""
    import ast
    from pathlib import Path

    from cartpole_warp.rl import loop
    from cartpole_warp.rl.learners import LEARNERS, learner_class

    assert len(Path(loop.__file__).read_text().splitlines()) <= 200
    package = Path(loop.__file__).parent.parent
    subclasses = [path.name for path in package.rglob("*.py") for node in ast.walk(ast.parse(path.read_text()))
                  if isinstance(node, ast.ClassDef) and any(getattr(base, "id", None) == "TrainingLoop"
                                                            for base in node.bases)]
    assert subclasses == []
    assert {name: learner_class(name).__name__ for name in LEARNERS} == {"ppo": "PpoLearner", "shac": "ShacLearner",
                                                                         "sapg": "SapgLearner",
                                                                         "fasttd3": "FastTd3Learner"}
    with pytest.raises(KeyError, match="no learner 'sac'; the learners: ppo, shac, sapg, fasttd3"):
        learner_class("sac")
