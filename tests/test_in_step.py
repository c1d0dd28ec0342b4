"""The evaluation inside the training's step (``eval.in_step``): its envs restart exactly as play.py's envs start, it
judges the same whole episodes as ``play.py --headless`` (``evaluate``) on the same policy and seed, the training's
envs step the same with or without it, and the verdict names (and ``model_best.pt`` keeps) the policy it froze."""

import json

import pytest
import torch
from conftest import DEVICE, SMALL_FRAMES, call_main, sees_images
from test_solved import BALANCING_GAINS, FAILING, make_training, set_policy_mean, training_episodes

from cartpole_warp import tasks
from cartpole_warp.evaluation.in_step import InStepEvaluation
from cartpole_warp.evaluation.rollouts import FirstEpisodesRun, evaluate
from cartpole_warp.evaluation.statistics import SolvedRule
from cartpole_warp.rl.runs import BEST_CHECKPOINT
from cartpole_warp.wrappers.rsl_rl import RslRlVecEnv

ROBUST = {"randomization": {"at": "reset", "mass_scale": {"cart": [0.7, 2.5]}, "actuator_scale": [0.6, 1.4],
                            "obs_noise_std": 0.01, "action_delay_steps": 2}}
"""Physics drawn at each episode start, observation noise and a random action delay: what a restart must draw (and
forget) as a fresh env does."""
SHORT_EPISODES = {"episode_length_s": 1.0}


def make(name: str, num_envs: int, seed: int, **overrides):
    """``name``'s env of ``num_envs`` on the test device with ``ROBUST`` randomization (a camera task's frames
    ``SMALL_FRAMES``), and ``overrides``."""
    if sees_images(name):
        overrides["camera"] = SMALL_FRAMES
    return tasks.make(name, num_envs=num_envs, device=DEVICE, seed=seed, **ROBUST, **overrides)


def linear_policy(env, seed: int = 0):
    """A fixed random linear map of the (flattened) observations to actions in [-1, 1]."""
    generator = torch.Generator().manual_seed(seed)
    size = int(torch.tensor(env.obs_buf.shape[1:]).prod())
    weights = (torch.randn(size, env.num_actions, generator=generator) / size ** 0.5).to(env.device)

    def act(obs):
        return torch.tanh(obs.reshape(obs.shape[0], -1).float() @ weights * 3)

    return act


@pytest.mark.parametrize("name", tasks.names())
def test_a_restarted_block_starts_and_steps_as_a_fresh_env_with_the_seed_and_the_others_go_on(name):
    big, reference, fresh = make(name, 12, seed=1), make(name, 12, seed=1), make(name, 8, seed=99)
    actions = torch.rand(30, 12, big.num_actions, generator=torch.Generator().manual_seed(0)) * 2 - 1
    for step in range(5):
        big.step(actions[step].to(DEVICE))
        reference.step(actions[step].to(DEVICE))
    obs = big.restart(4, 12, seed=7)
    assert torch.equal(obs[4:], fresh.reset(7)[0]), "the block starts as a fresh env reset with the seed"
    for name_, value in big.physical_params().items():
        assert torch.equal(value[4:], fresh.physical_params()[name_]), name_
    for step in range(5, 30):
        stepped = big.step(actions[step].to(DEVICE))
        alone = fresh.step(actions[step, 4:].to(DEVICE))
        beside = reference.step(actions[step].to(DEVICE))
        for got, block, rest in zip(stepped[:4], alone[:4], beside[:4]):
            assert torch.equal(got[4:], block), f"step {step}: the block steps as the fresh env"
            assert torch.equal(got[:4], rest[:4]), f"step {step}: the other envs are undisturbed"


@pytest.mark.parametrize("name", tasks.names())
def test_the_in_step_evaluation_judges_the_episodes_play_plays(name):
    """A block of 8 beside 8 training envs under random training actions, with a fixed policy, judged over whole
    episodes of 1 s (a rule that is never hopeless), gives the summary ``evaluate`` gives on a fresh env of 8
    (play.py's)."""
    env = make(name, 16, seed=3, task=SHORT_EPISODES)
    evaluation = InStepEvaluation(env, 8, seed=5)
    evaluation.policy = linear_policy(env)
    vec_env = RslRlVecEnv(env, evaluation)
    assert vec_env.num_envs == 8 and vec_env.get_observations().batch_size == torch.Size([8])
    evaluation.begin()
    generator = torch.Generator().manual_seed(1)
    judged = None
    while judged is None:
        for _ in range(10):
            vec_env.step((torch.rand(8, env.num_actions, generator=generator) * 2 - 1).to(DEVICE))
        judged = evaluation.verdict(10, SolvedRule())
    played = evaluate(FirstEpisodesRun(make(name, 8, seed=0, task=SHORT_EPISODES), evaluation.policy, capture=False),
                      5)
    assert judged == played and judged.cut_at_step is None
    assert not evaluation.running


@pytest.mark.parametrize("name", tasks.names())
def test_the_training_envs_step_the_same_with_the_evaluation_envs_beside_them(name, tmp_path):
    """A run's third rollout (observations, actions, rewards, dones) and its networks after three updates, same seed,
    with and without ``eval.in_step``: an evaluation is due after every iteration, so the evaluation's envs restart
    after the first and step through the rollouts compared."""
    from cartpole_warp.rl.config import train_config
    from cartpole_warp.rl.training import Training

    runs = []
    for in_step in (False, True):
        cfg = train_config(name, device=DEVICE)
        cfg.env.num_envs, cfg.env.device, cfg.agent.logger, cfg.log_dir = 16, DEVICE, "none", str(tmp_path)
        cfg.eval.num_envs, cfg.eval.in_step, cfg.eval.min_interval, cfg.eval.max_interval = 8, in_step, 1, 1
        cfg.env.camera.width_px = cfg.env.camera.height_px = 36  # the smallest frames the pixel tasks' CNN takes
        training = Training(cfg, tmp_path / f"run{in_step}")
        assert (training.loop.env.evaluation is not None) == in_step and training.env.num_envs == 16
        training.loop.learn(3)
        runs.append(training.loop)
    assert runs[1].evaluations.in_step.judged_policy is not None, \
        "evaluations began (the first after iteration 0: its envs restarted)"
    storages = [runner.learner.alg.storage for runner in runs]
    for field in ("actions", "rewards", "dones"):
        assert torch.equal(*(getattr(storage, field) for storage in storages)), field
    for group in sorted(storages[0].observations.keys()):  # a TensorDict iterates over its rows
        assert torch.equal(*(storage.observations[group] for storage in storages)), group
    policies = [runner.learner.alg.get_policy().state_dict() for runner in runs]
    for key, value in policies[0].items():
        assert torch.equal(value, policies[1][key]), key


def test_the_verdict_names_the_frozen_policy_keeps_it_as_best_and_a_hopeless_one_is_cut(tmp_path, capsys):
    """The policy after iteration 0 balances and is frozen; the runner's own policy then pushes nothing. The verdict
    comes once every episode has run to the time limit (600 env steps: 75 iterations of 8), solved, naming iteration
    0, whose policy ``model_best.pt`` holds; the next evaluation, of the pushing-nothing policy, is cut once its
    failures rule 'solved' out. ``play.py --headless`` on the run plays the judged episodes."""
    training = make_training(tmp_path, min_interval=1, max_interval=1, in_step=True)
    set_policy_mean(training, BALANCING_GAINS, std=1.0)
    training_episodes(training, FAILING)
    training.loop.on_iteration = lambda it, stats: set_policy_mean(training, [0.0, 0.0, 0.0, 0.0], std=1.0)
    steps_per_iteration = training.cfg.agent.num_steps_per_env
    iterations = training.max_episode_length // steps_per_iteration
    training.loop.learn(2 * iterations + 1)
    verdicts = [h for h in training.loop.records[0].progress.history if "evaluation" in h]
    assert [h["iteration"] for h in verdicts][0] == iterations
    solved = verdicts[0]["evaluation"]
    assert solved["policy_iteration"] == 0 and solved["time_limit_fraction"] == 1.0 and solved["cut_at_step"] is None
    assert verdicts[0]["solved"] and training.loop.records[0].progress.solved_at["iterations"] == 1
    line = next(line for line in capsys.readouterr().out.splitlines() if "SOLVED" in line)
    assert line.startswith(f"it  {iterations + 1}/") and "eval of it 1's policy time_limit_fraction 1.000" in line
    assert training.loop.records[0].progress.best == {"iteration": 0, "solved": True, "time_limit_fraction": 1.0}
    best = torch.load(training.run_dir / BEST_CHECKPOINT, weights_only=False)
    assert best["iter"] == 0 and best["infos"]["iterations"] == 1, "resuming from it continues the judged policy"
    progress = training.loop.records[0].progress
    assert best["infos"]["best"] == progress.best and best["infos"]["solved_at"]["iterations"] == 1
    assert torch.equal(best["actor_state_dict"]["mlp.0.weight"][0].cpu(), torch.tensor(BALANCING_GAINS))
    played = call_main("play", "--headless", "--run", training.run_dir, "--num-envs", training.cfg.eval.num_envs)
    assert played.returncode == 0, played.stderr
    result = json.loads((training.run_dir / "play" / "result.json").read_text())
    assert [result[key] for key in ("episodes", "mean_return", "time_limit_fraction")] == [
        solved[key] for key in ("episodes", "mean_return", "time_limit_fraction")], "play.py plays the judged episodes"
    cut = verdicts[1]["evaluation"]
    assert cut["policy_iteration"] == iterations and not verdicts[1]["solved"]
    assert cut["cut_at_step"] is not None and cut["cut_at_step"] < training.max_episode_length
    assert cut["time_limit_fraction"] == 0.0
