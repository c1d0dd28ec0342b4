"""The stop rule judges the deterministic policy over whole episodes, as play.py does: a policy that meets the task's
rule only in its (noisy) training episodes is not solved, one whose mean action balances is solved whatever its
training episodes show, the best evaluation is kept as model_best.pt and play.py loads it by default."""

import dataclasses
import signal

import pytest
import torch
from conftest import DEVICE

from cartpole_warp import tasks
from cartpole_warp.evaluation.rollouts import FirstEpisodesRun, evaluate
from cartpole_warp.evaluation.statistics import EpisodeSummary
from cartpole_warp.rl.config import train_config
from cartpole_warp.rl.runs import BEST_CHECKPOINT, list_checkpoints, play_checkpoint
from cartpole_warp.rl.training import Training

BALANCING_GAINS = [0.05, 0.1, -2.0, -0.3]
"""A linear state feedback (action per cart_pos, cart_vel, pole_angle, pole_vel) that keeps the balance task's pole
up for the whole 10 s from every start (found by a grid search over the env itself)."""
PASSING = EpisodeSummary(100, 590.0, 595.0, 0.99, 1.0, 100, 0.99)
FAILING = EpisodeSummary(100, 10.0, 20.0, 0.5, 0.0)


def make_training(tmp_path, logger="none", **eval_settings) -> Training:
    """A balance run of 64 training envs and 32 evaluation envs on the test device that barely learns (fixed learning
    rate of 1e-12): its policy stays the one the test writes into the actor. It trains all its iterations unless a
    test sets ``stop_when_solved``."""
    cfg = train_config("cartpole-balance")
    cfg.env.num_envs, cfg.env.device, cfg.agent.logger, cfg.log_dir = 64, DEVICE, logger, str(tmp_path)
    cfg.stop_when_solved = False
    cfg.agent.algorithm.schedule, cfg.agent.algorithm.learning_rate = "fixed", 1e-12
    for name, value in {"num_envs": 32, **eval_settings}.items():
        setattr(cfg.eval, name, value)
    return Training(cfg, tmp_path / "run")


def set_policy_mean(training: Training, gains: list[float], std: float):
    """The actor's mean action becomes ``gains @ obs`` exactly (ELU is the identity on the positive side, so the
    hidden layers carry ``gains @ obs + 10`` through unit 0), its Gaussian noise ``std``."""
    actor = training.loop.learner.alg.get_policy()
    with torch.no_grad():
        for param in actor.parameters():
            param.zero_()
        first, second, out = actor.mlp[0], actor.mlp[2], actor.mlp[4]
        first.weight[0] = torch.tensor(gains)
        first.bias[0] = 10.0
        second.weight[0, 0] = 1.0
        out.weight[0, 0] = 1.0
        out.bias[0] = -10.0
        actor.distribution.std_param.fill_(std)


def training_episodes(training: Training, summary: EpisodeSummary):
    """The runner sees ``summary`` as every iteration's training episodes (what a noisy policy showed)."""
    training.loop.learner.episodes.pop = lambda all_processes=False: summary


def test_training_episodes_that_meet_the_rule_do_not_make_a_failing_policy_solved(tmp_path):
    training = make_training(tmp_path, min_interval=1, max_interval=100)
    set_policy_mean(training, [0.0, 0.0, 0.0, 0.0], std=1.0)
    training_episodes(training, PASSING)
    training.cfg.stop_when_solved = training.loop.records[0].config.stop_when_solved = True
    training.loop.learn(3)
    history = training.loop.records[0].progress.history
    assert [h["solved"] for h in history] == [False] * 3, "a push of 0 lets every pole fall"
    assert all(h["evaluation"]["time_limit_fraction"] == 0.0 for h in history), "each candidate was evaluated"
    assert training.loop.records[0].progress.solved_at is None and training.loop.records[0].stop_reason is None


def test_a_balancing_mean_is_solved_at_the_periodic_evaluation_and_training_stops_there_by_default(tmp_path):
    training = make_training(tmp_path, logger="tensorboard", min_interval=1, max_interval=3)
    set_policy_mean(training, BALANCING_GAINS, std=5.0)
    training_episodes(training, FAILING)
    training.loop.records[0].config.stop_when_solved = train_config().stop_when_solved  # train.py's default: stop
    training.loop.learn(10)
    history = training.loop.records[0].progress.history
    assert ["evaluation" in h for h in history] == [False, False, True], "no candidate: the third iteration looks"
    assert history[-1]["evaluation"]["time_limit_fraction"] == 1.0 and history[-1]["solved"]
    assert training.loop.records[0].stop_reason == "solved"
    assert training.loop.records[0].progress.solved_at["iterations"] == 3

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(training.run_dir)).Reload()
    assert [(e.step, e.value) for e in events.Scalars("Eval/time_limit_fraction")] == [(2, 1.0)], "TensorBoard"
    assert [e.step for e in events.Scalars("Perf/total_fps")] == [0, 1, 2], "every iteration's scalars"
    assert events.Tags()["scalars"] and set(events.Tags()["scalars"]) >= {"Loss/learning_rate", "Policy/mean_std"}


def test_the_evaluation_is_play_and_its_best_policy_is_what_play_loads(tmp_path):
    training = make_training(tmp_path, min_interval=1, max_interval=1)
    set_policy_mean(training, BALANCING_GAINS, std=1.0)
    training_episodes(training, FAILING)
    training.loop.on_iteration = lambda it, stats: set_policy_mean(training, [0.0, 0.0, 0.0, 0.0], std=1.0)
    training.loop.learn(2)
    history, run = training.loop.records[0].progress.history, training.run_dir
    assert [h["evaluation"]["time_limit_fraction"] for h in history] == [1.0, 0.0]
    assert training.loop.records[0].progress.best == {"iteration": 0, "solved": True, "time_limit_fraction": 1.0}
    assert play_checkpoint(run) == run / BEST_CHECKPOINT and list_checkpoints(run)[-1].name == "model_1.pt"
    best = torch.load(run / BEST_CHECKPOINT, weights_only=False)
    assert best["iter"] == 0
    assert torch.equal(best["actor_state_dict"]["mlp.0.weight"][0].cpu(), torch.tensor(BALANCING_GAINS))

    # what play.py plays: the run's seed, a fresh env of eval.num_envs envs, the best checkpoint's policy
    from cartpole_warp.rl.loop import TrainingLoop
    from cartpole_warp.wrappers.rsl_rl import RslRlVecEnv

    cfg = training.cfg
    env = tasks.get(cfg.task).env_class(dataclasses.replace(cfg.env, num_envs=cfg.eval.num_envs))
    player = TrainingLoop(RslRlVecEnv(env), cfg, None)
    player.records[0].load(str(play_checkpoint(run)), load_cfg={"actor": True})
    played = evaluate(FirstEpisodesRun(env, player.records[0].policy()), cfg.env.seed)
    evaluated = history[0]["evaluation"]
    assert (played.episodes, played.mean_return, played.time_limit_fraction) == (
        evaluated["episodes"], evaluated["mean_return"], evaluated["time_limit_fraction"]), "the same episodes"


def test_an_evaluation_stops_once_its_failures_rule_solved_out_and_keeps_the_whole_runs_verdict():
    """With the task's rule, an evaluation whose failed episodes already keep the rule from being met stops there
    (a fallen pole's episode cannot come back); one that may still be solved runs every episode to its end and gives
    what the whole run gives."""
    env = tasks.make("cartpole-balance", num_envs=32, device=DEVICE, seed=5)
    rule = tasks.get("cartpole-balance").solved
    gains = torch.tensor(BALANCING_GAINS, device=DEVICE)
    for name, policy in (("no push", lambda obs: torch.zeros(obs.shape[0], 1, device=obs.device)),
                         ("balancing", lambda obs: (obs @ gains)[:, None])):
        whole, cut = (evaluate(FirstEpisodesRun(env, policy), 3, with_rule) for with_rule in (None, rule))
        assert whole.cut_at_step is None and rule(whole) == rule(cut) == (name == "balancing"), name
        if name == "balancing":
            assert cut == whole, "a run that may still be solved is not cut"
        else:
            assert cut.cut_at_step < env.max_episode_length and cut.cut_at_step % 25 == 0
            assert 2 <= cut.episodes < whole.episodes == 32 and cut.time_limit_fraction == 0.0, \
                "the cut counts the episodes that had ended: failures, at least 2 of 32 (95% must reach the limit)"


def test_a_rule_is_hopeless_once_too_many_episodes_failed_for_its_time_limit_fraction():
    rule = tasks.get("cartpole-balance").solved
    assert rule.min_time_limit_fraction == 0.95
    assert not rule.hopeless(12, 256) and rule.hopeless(13, 256)  # 244 / 256 = 0.953, 243 / 256 = 0.949
    assert not dataclasses.replace(rule, min_time_limit_fraction=0.0).hopeless(256, 256), "no fraction: never"


@pytest.mark.parametrize("name", tasks.names())
def test_every_tasks_rule_refuses_a_summary_without_episodes(name):
    assert not tasks.get(name).solved(EpisodeSummary(0, None, None, None, None))


def test_the_learning_curve_shows_the_whole_run_not_the_progress_saved_with_the_best_checkpoint(tmp_path):
    """The export after training loads model_best.pt's policy: the run's own history (every iteration) stays what
    the learning curve is drawn from and summary.json counts."""
    training = make_training(tmp_path, min_interval=1, max_interval=1)
    training.cfg.agent.max_iterations = 3
    set_policy_mean(training, BALANCING_GAINS, std=1.0)
    training_episodes(training, FAILING)
    training.loop.on_iteration = lambda it, stats: set_policy_mean(training, [0.0, 0.0, 0.0, 0.0], std=1.0)
    summary = training.run()
    assert summary.best["iteration"] == 0 and summary.iterations == 3
    assert [h["iteration"] for h in training.loop.records[0].progress.history] == [0, 1, 2], "the curve's history"


@pytest.mark.parametrize("signals", [1, 2])
def test_a_signal_once_training_has_ended_waits_for_the_summary(tmp_path, signals, capsys):
    """SIGINT delivered while the policy is exported (right after the last iteration line, e.g. one reading SOLVED),
    once or twice: the exports, the curve and summary.json are still written, and the run's status is what training
    reached."""
    training = make_training(tmp_path)
    training.cfg.agent.max_iterations = 1
    export = training.loop.records[0].export

    def export_under_signals(out_dir):
        for _ in range(signals):
            signal.raise_signal(signal.SIGINT)
        return export(out_dir)

    training.loop.records[0].export = export_under_signals
    handler = signal.getsignal(signal.SIGINT)  # Python's, or pytest-xdist's worker's SIG_IGN
    summary = training.run()
    assert summary.status == "completed" and (training.run_dir / "summary.json").is_file()
    assert (training.run_dir / "learning_curve.png").is_file()
    assert summary.exports == ["exported/policy.onnx", "exported/policy.pt2", "exported/policy.pt"]
    assert "writing the run's exports, curve and summary first" in capsys.readouterr().out
    assert signal.getsignal(signal.SIGINT) is handler, "the handler is restored"
