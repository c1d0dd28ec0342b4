"""Training by analytic policy gradients through the simulator (``--learner shac``, ``rl.learners.shac``): the critic's
TD(lambda) targets against their definition, the learner's settings and refusals, a run on every state task, a
resumed run, and the balance trained to solved and played by ``play.py --headless``."""

import json

import pytest
import torch
from conftest import call_main
from test_train_cli import only_run, train_to_solved_and_play

from cartpole_warp import tasks
from cartpole_warp.rl.config import learner_defaults, train_config
from cartpole_warp.rl.learners.shac.learner import window_targets

STATE_TASKS = [name for name in tasks.names() if not train_config(name).env.camera.enabled]


def lambda_return_by_definition(rewards, next_values, terminated, ended, gamma, lam, t):
    """TD(lambda) return of step t as the lambda-weighted mean of its n-step returns (Sutton & Barto, eq. 12.3),
    truncated at the episode's end (a termination's value is 0) or at the window's end."""
    horizon = len(rewards)
    stop = next((k for k in range(t, horizon) if ended[k]), horizon - 1)  # the last step this return can see

    def n_step(n):
        last = t + n - 1
        ret = sum(gamma ** (k - t) * rewards[k] for k in range(t, last + 1))
        return ret + (0.0 if terminated[last] else gamma ** n * next_values[last])

    steps = stop - t + 1
    return (1 - lam) * sum(lam ** (n - 1) * n_step(n) for n in range(1, steps)) + lam ** (steps - 1) * n_step(steps)


@pytest.mark.parametrize("case", ["running", "terminated", "timed out"])
def test_the_critics_targets_are_lambda_returns(case):
    generator = torch.Generator().manual_seed(3)
    horizon, gamma, lam = 6, 0.9, 0.7
    rewards, next_values = torch.rand(horizon, 1, generator=generator), torch.rand(horizon, 1, generator=generator)
    terminated, ended = torch.zeros(horizon, 1, dtype=torch.bool), torch.zeros(horizon, 1, dtype=torch.bool)
    if case != "running":
        ended[3] = True
        terminated[3] = case == "terminated"
    targets = window_targets(rewards, next_values, terminated, ended, gamma, lam)
    for t in range(4 if case != "running" else horizon):  # the steps after an end are not trained on
        expected = lambda_return_by_definition(rewards[:, 0].tolist(), next_values[:, 0].tolist(),
                                               terminated[:, 0].tolist(), ended[:, 0].tolist(), gamma, lam, t)
        assert targets[t, 0].item() == pytest.approx(expected, rel=1e-5), t


def test_the_learner_chooses_its_own_settings_and_says_so(tmp_path):
    cfg = train_config("cartpole-balance", learner="shac")
    chosen = learner_defaults(tasks.get("cartpole-balance"), "shac")
    assert cfg.agent.learner == "shac" and cfg.env.num_envs == chosen["env"]["num_envs"] != train_config().env.num_envs
    assert cfg.agent.num_steps_per_env == chosen["agent"]["num_steps_per_env"]
    result = call_main("train", "--learner", "shac", "--num-envs", "8", "--max-iterations", "1", "--device", "cpu",
                       "--logger", "none", "--log-dir", tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert ("with --learner shac its settings and the task's: env.num_envs 8, agent.num_steps_per_env 32"
            in result.stdout)


@pytest.mark.parametrize(("flags", "message"), [
    (["--task", "cartpole-balance-rgb"], "a task that observes camera frames"),
    (["--env.sim.solver", "mujoco"], "env.sim.solver other than featherstone"),
    (["--env.randomization.action-delay-steps", "2"], "env.randomization.action_delay_steps"),
    (["--env.randomization.obs-noise-std", "0.1"], "env.randomization.obs_noise_std"),
])
def test_what_the_learner_cannot_train_is_one_clear_error(tmp_path, flags, message):
    result = call_main("train", "--learner", "shac", "--num-envs", "4", "--max-iterations", "1", "--device", "cpu",
                       "--logger", "none", "--log-dir", tmp_path, *flags)
    assert result.returncode != 0 and message in result.stderr, result.stdout + result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize("task", STATE_TASKS)
def test_every_state_task_trains_a_few_windows_and_resumes(tmp_path, task):
    """Two iterations of 8 envs and 4-step windows, then one more from the checkpoint: the losses are finite, the
    actor moves, and a resumed run takes the learner's optimizers and target critic back."""
    common = ["--task", task, "--num-envs", "8", "--agent.num-steps-per-env", "4", "--device", "cpu", "--logger",
              "none", "--log-dir", tmp_path, "--no-stop-when-solved"]
    result = call_main("train", "--learner", "shac", "--max-iterations", "2", *common)
    assert result.returncode == 0, result.stdout + result.stderr
    run = only_run(tmp_path, task)
    first = torch.load(run / "model_1.pt", weights_only=False)
    assert set(first["apg_state_dict"]) == {"actor_optimizer", "critic_optimizer", "target_critic"}
    assert first["apg_state_dict"]["actor_optimizer"]["state"], "the actor's optimizer took steps"
    summary = json.loads((run / "summary.json").read_text())
    assert summary["iterations"] == 2 and summary["env_steps"] == 2 * 8 * 4
    result = call_main("train", "--resume", run, "--max-iterations", "1", *common[2:])
    assert result.returncode == 0, result.stdout + result.stderr
    resumed = torch.load(run / "model_2.pt", weights_only=False)
    assert resumed["iter"] == 2
    moved = [not torch.equal(resumed["actor_state_dict"][k], first["actor_state_dict"][k])
             for k in first["actor_state_dict"] if k.startswith("mlp")]
    assert any(moved), "the resumed iteration moved the actor"
    steps = [s["step"] for s in resumed["apg_state_dict"]["actor_optimizer"]["state"].values()]
    assert all(step == 3 for step in steps), "Adam's step counts carried over the resume"


@pytest.mark.slow
def test_the_balance_trains_to_solved_by_backpropagation_and_plays(tmp_path):
    """The learner's defaults on the balance: solved (the same rule, the same evaluation) and replayed by play.py."""
    summary, played = train_to_solved_and_play(tmp_path, "cartpole-balance", "--learner", "shac")
    assert summary["num_envs"] == learner_defaults(tasks.get("cartpole-balance"), "shac")["env"]["num_envs"]
    assert played["time_limit_fraction"] >= 0.95 and played["mean_reward_per_step"] >= 0.9


def test_a_presets_settings_win_over_the_learners_and_flags_over_both():
    """Precedence: the learner's defaults < the preset < the flags (``--config tutorial --learner shac`` built the
    learner's 64 envs instead of the tutorial's one)."""
    from cartpole_warp.train import resolve

    chosen = learner_defaults(tasks.get("cartpole-balance"), "shac")
    cfg = train_config("cartpole-balance", "tutorial", learner="shac")
    assert cfg.env.num_envs == 1 != chosen["env"]["num_envs"], "the preset's env count"
    assert cfg.agent.num_steps_per_env == chosen["agent"]["num_steps_per_env"], "the learner's, the preset silent"
    flagged, _, _ = resolve(["--config", "tutorial", "--learner", "shac", "--num-envs", "3"])
    assert flagged.env.num_envs == 3 and flagged.agent.learner == "shac"
