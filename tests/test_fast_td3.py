"""The off-policy learner (``--learner fasttd3``, ``rl.learners.fast_td3``): its categorical projection against C51's
formula, its critic and actor losses against their definitions on a small batch, its replay, the transitions it stores
against the tutorial's termination rule; it trains the balance to solved, its folder plays and its exports act as its
actor (tanh of the mean); the same seed trains the same run; what it cannot train is one line."""

import json
import math

import pytest
import torch
from conftest import call_main
from test_train_cli import only_run

from cartpole_warp.rl.config import train_config
from cartpole_warp.rl.learners.fast_td3.update import (
    Replay,
    TwinDistributionalCritic,
    actor_loss,
    critic_loss,
    project,
)
from cartpole_warp.rl.runs import BEST_CHECKPOINT, SUMMARY_FILE
from cartpole_warp.rl.training import Training


def c51_projection(probabilities, rewards, discounts, support):
    """Bellemare et al.'s projection, atom by atom: (Phi T z_j)_i = sum_j [1 - |[r + d z_j] - z_i| / dz]_0^1 p_j."""
    dz = (support[-1] - support[0]) / (len(support) - 1)
    out = torch.zeros_like(probabilities)
    for b in range(probabilities.shape[0]):
        for j, z_j in enumerate(support):
            shifted = min(max(rewards[b] + discounts[b] * z_j, support[0]), support[-1])
            for i, z_i in enumerate(support):
                out[b, i] += max(0.0, 1 - abs(shifted - z_i) / dz) * probabilities[b, j]
    return out


def test_the_projection_is_c51s():
    """Random distributions on 11 atoms of [-2, 3], shifted by rewards and discounts that put atoms past both ends,
    onto other atoms exactly, and a termination (discount 0): the mass of each atom as C51 defines it."""
    torch.manual_seed(0)
    support = torch.linspace(-2.0, 3.0, 11)
    probabilities = torch.softmax(torch.randn(5, 11), dim=-1)
    rewards = torch.tensor([0.3, -1.0, 2.5, 0.5, 1.0])
    discounts = torch.tensor([0.99, 0.9, 0.99, 1.0, 0.0])
    projected = project(probabilities, rewards, discounts, support)
    torch.testing.assert_close(projected, c51_projection(probabilities, rewards.tolist(), discounts.tolist(),
                                                         support.tolist()), rtol=0, atol=1e-6)
    torch.testing.assert_close(projected.sum(-1), torch.ones(5))
    assert projected[4, 6] == pytest.approx(1.0), "a termination: all the mass on the atom of the reward (1.0)"


def small_critics(seed=1):
    torch.manual_seed(seed)
    critic = TwinDistributionalCritic(3, 1, [8], 7, -1.0, 2.0)
    target = TwinDistributionalCritic(3, 1, [8], 7, -1.0, 2.0)
    return critic, target


def test_the_critic_loss_is_clipped_double_q_cross_entropy_to_the_projected_target():
    """Per transition: both target critics' distributions at (s', a'), projected with r and the discount; the one
    whose mean is lower is the target of both critics; the loss is the sum of their mean cross-entropies."""
    critic, target = small_critics()
    torch.manual_seed(2)
    obs, actions, next_obs, next_actions = torch.randn(4, 3), torch.rand(4, 1) * 2 - 1, torch.randn(4, 3), torch.rand(
        4, 1) * 2 - 1
    rewards, discounts = torch.tensor([0.5, -0.2, 1.0, 0.0]), torch.tensor([0.99, 0.0, 0.99, 0.99])
    support = critic.support.tolist()
    expected = 0.0
    for b in range(4):
        x, x_next = torch.cat([obs[b], actions[b]]), torch.cat([next_obs[b], next_actions[b]])
        targets = [c51_projection(torch.softmax(net(x_next), -1)[None], [rewards[b].item()], [discounts[b].item()],
                                  support)[0] for net in target.critics]
        means = [sum(p * z for p, z in zip(t.tolist(), support)) for t in targets]
        chosen = targets[0] if means[0] < means[1] else targets[1]
        for net in critic.critics:
            expected += -(chosen * torch.log_softmax(net(x), -1)).sum().item() / 4
    loss = critic_loss(critic, target, obs, actions, rewards, discounts, next_obs, next_actions)
    assert loss.item() == pytest.approx(expected, rel=1e-5)
    loss.backward()
    assert all(p.grad is not None for p in critic.parameters()) and all(p.grad is None for p in target.parameters())


def test_the_actor_loss_is_minus_the_mean_of_the_smaller_expected_return():
    critic, _ = small_critics()
    torch.manual_seed(3)
    obs, actions = torch.randn(6, 3), torch.tanh(torch.randn(6, 1))
    support = critic.support
    values = [[(torch.softmax(net(torch.cat([obs[b], actions[b]])), -1) * support).sum().item() for b in range(6)]
              for net in critic.critics]
    expected = -sum(min(v1, v2) for v1, v2 in zip(*values)) / 6
    assert actor_loss(critic, obs, actions).item() == pytest.approx(expected, rel=1e-5)


def test_the_replay_keeps_the_last_steps_and_samples_only_what_was_written():
    replay = Replay(steps=3, num_envs=2, num_obs=1, num_actions=1, device="cpu")
    for step in range(5):  # steps 2, 3, 4 stay
        value = torch.full((2, 1), float(step))
        replay.add(value, value, value[:, 0], torch.full((2,), 0.99), value + 0.5)
    torch.manual_seed(0)
    obs, actions, rewards, discounts, next_obs = replay.sample(200)
    assert set(obs.flatten().tolist()) == {2.0, 3.0, 4.0}
    assert torch.equal(actions, obs) and torch.equal(rewards, obs[:, 0]) and torch.equal(next_obs, obs + 0.5)
    assert torch.all(discounts == 0.99)
    fresh = Replay(steps=10, num_envs=2, num_obs=1, num_actions=1, device="cpu")
    fresh.add(torch.ones(2, 1), torch.ones(2, 1), torch.ones(2), torch.ones(2), torch.ones(2, 1))
    assert torch.all(fresh.sample(50)[0] == 1.0), "only the one step written"


def tutorial_terminal(states: torch.Tensor) -> torch.Tensor:
    """The tutorial's termination: |cart_pos| > 3 m or |pole_angle| > pi / 2 (observation [x, x_dot, theta, ...])."""
    return (states[:, 0].abs() > 3.0) | (states[:, 2].abs() > math.pi / 2)


def test_the_stored_transitions_discount_terminations_to_zero_and_end_on_the_final_state(tmp_path):
    """Four iterations of the balance with a fresh actor, wild actions and a time limit of 12 steps (episodes fail
    and time out): a transition's discount is 0 exactly where its next state is terminal by the tutorial's rule,
    gamma elsewhere (time-outs bootstrap)."""
    cfg = train_config(learner="fasttd3")
    cfg.env.num_envs, cfg.env.device, cfg.agent.logger, cfg.agent.max_iterations = 32, "cpu", "none", 4
    cfg.env.task.episode_length_s = 0.2
    cfg.agent.fasttd3.batch_size, cfg.agent.fasttd3.critic_hidden_dims = 64, [16]
    cfg.agent.fasttd3.std_min = cfg.agent.fasttd3.std_max = 1.0  # wild actions: many terminations
    training = Training(cfg, tmp_path)
    training.run()
    replay = training.loop.learner.replay
    steps = int(replay.filled.item())
    rows = replay.data[:steps].flatten(0, 1)
    obs, actions, _, discounts, next_obs = rows.split(replay.widths, dim=-1)
    terminal = tutorial_terminal(next_obs)
    assert terminal.sum() > 10, "episodes failed"
    history = training.loop.records[0].progress.history
    assert any((h["time_limit_fraction"] or 0) > 0 for h in history), "episodes timed out"
    assert torch.equal(discounts[:, 0] == 0.0, terminal)
    assert torch.all(discounts[~terminal] == torch.tensor(cfg.agent.fasttd3.gamma))
    assert torch.all(actions.abs() <= 1.0)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:`torch.jit.load` is deprecated")
def test_fasttd3_trains_the_balance_to_solved_with_its_cpu_defaults_and_its_folder_plays_and_exports_its_actor(
        tmp_path):
    """``train.py --learner fasttd3 --device cpu`` (its CPU sizes: 256 envs, batch 512, a 128-128 critic) solves the
    balance within the task's budget; play.py plays the folder; the TorchScript export is tanh of the actor's MLP on the
    normalised observations, computed here from the checkpoint's tensors."""
    result = call_main("train", "--learner", "fasttd3", "--device", "cpu", "--logger", "none", "--log-dir", tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    run = only_run(tmp_path)
    summary = json.loads((run / SUMMARY_FILE).read_text())
    assert summary["status"] == "solved", summary
    played = call_main("play", "--headless", "--run", run, "--num-envs", "16")
    assert played.returncode == 0, played.stdout + played.stderr
    assert "solved" in played.stdout.lower(), played.stdout
    checkpoint = torch.load(run / BEST_CHECKPOINT, weights_only=False)
    actor = checkpoint["actor_state_dict"]
    exported = torch.jit.load(run / "exported" / "policy.pt")
    obs = torch.randn(32, 4) * torch.tensor([1.0, 0.5, 0.4, 0.8])
    mean, std = actor["obs_normalizer._mean"], actor["obs_normalizer._std"]
    x = (obs - mean) / (std + 1e-2)
    layers = sorted({key.rsplit(".", 1)[0] for key in actor if key.startswith("mlp.")}, key=lambda k: int(k[4:]))
    for i, layer in enumerate(layers):
        x = x @ actor[f"{layer}.weight"].T + actor[f"{layer}.bias"]
        x = torch.nn.functional.elu(x) if i < len(layers) - 1 else torch.tanh(x)
    torch.testing.assert_close(exported(obs), x, rtol=1e-5, atol=1e-5)


def test_a_checkpoint_of_a_gpu_run_resumes_on_a_cpu(tmp_path):
    """A GPU run's optimizers step inside captured graphs (torch's capturable AdamW, step counts on the device): its
    checkpoint loaded by a CPU run steps as the CPU's own optimizers do."""
    cfg = train_config(learner="fasttd3")
    cfg.env.num_envs, cfg.env.device, cfg.agent.logger, cfg.agent.max_iterations = 16, "cpu", "none", 1
    cfg.agent.fasttd3.batch_size, cfg.agent.fasttd3.critic_hidden_dims = 64, [16]
    training = Training(cfg, tmp_path)
    training.run()
    learner = training.loop.learner
    state = learner.state_dict()
    for part in ("actor", "critic"):  # as a GPU run saves them
        for group in state["optimizer_state_dict"][part]["param_groups"]:
            group["capturable"] = True
    learner.load_state_dict(state, None, strict=True)
    assert all(not group["capturable"] for group in learner.critic_optimizer.param_groups)
    learner.iteration(training.env.get_observations(), 1)
    assert torch.isfinite(torch.cat([p.flatten() for p in learner.critic.parameters()])).all()


def test_fasttd3_is_judged_inside_the_training_step_where_asked(tmp_path):
    """``eval.in_step`` (off in the learner's defaults): the evaluation's envs step beside the training's, with a
    frozen copy of the actor, and their verdicts reach the run's books."""
    cfg = train_config(learner="fasttd3")
    cfg.env.num_envs, cfg.env.device, cfg.agent.logger, cfg.agent.max_iterations = 16, "cpu", "none", 12
    cfg.agent.fasttd3.batch_size, cfg.agent.fasttd3.critic_hidden_dims = 64, [16]
    cfg.eval.in_step, cfg.eval.num_envs, cfg.eval.min_interval, cfg.eval.max_interval = True, 8, 1, 2
    training = Training(cfg, tmp_path)
    assert training.env.evaluation is not None and training.loop.learner.replay.num_envs == 16
    training.run()
    judged = [h["evaluation"] for h in training.loop.records[0].progress.history if "evaluation" in h]
    assert judged and all(verdict["episodes"] > 0 for verdict in judged)


def test_the_same_seed_trains_the_same_fasttd3_run(tmp_path):
    weights = []
    for name in ("a", "b"):
        cfg = train_config(learner="fasttd3")
        cfg.env.num_envs, cfg.env.device, cfg.agent.logger, cfg.agent.max_iterations = 16, "cpu", "none", 3
        cfg.agent.fasttd3.batch_size, cfg.agent.fasttd3.critic_hidden_dims = 64, [16]
        training = Training(cfg, tmp_path / name)
        training.run()
        weights.append(training.loop.learner.state_dict())
    for part in ("actor_state_dict", "critic_state_dict"):
        assert all(torch.equal(weights[0][part][key], value) for key, value in weights[1][part].items()), part


@pytest.mark.parametrize(("flags", "message"), [
    (["--task", "cart-double-pole-balance-rgb"], "--learner fasttd3 cannot train cart-double-pole-balance-rgb with a "
                                                 "task that observes camera frames"),
    (["--agent.fasttd3.v-min", "5", "--agent.fasttd3.v-max", "1"], "agent.fasttd3.v_min 5 >= v_max 1"),
    (["--seeds", "0", "1"], "cannot train with --learner fasttd3"),
])
def test_what_fasttd3_cannot_train_is_one_line(tmp_path, flags, message):
    result = call_main("train", "--learner", "fasttd3", *flags, "--device", "cpu", "--max-iterations", "1",
                       "--logger", "none", "--log-dir", tmp_path)
    assert result.returncode != 0 and message in result.stderr, result.stdout + result.stderr
    assert "Traceback" not in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_graphed_fasttd3_iterations_equal_launched_ones(device, tmp_path):
    """On a GPU (``CARTPOLE_TEST_DEVICE=cuda:0``) the rollout and the updates are captured as CUDA graphs, the
    optimizers stepping inside them (capturable AdamW): four iterations give the networks that the same iterations
    launched op by op give (to float rounding: 8 of 16,384 critic weights differed by up to 2.4e-5 on an H200)."""
    if not device.startswith("cuda"):
        pytest.skip("CUDA graphs need a GPU: CARTPOLE_TEST_DEVICE=cuda:0")
    learners = []
    for graphed in (True, False):
        cfg = train_config(learner="fasttd3")
        cfg.env.num_envs, cfg.env.device, cfg.agent.logger, cfg.agent.max_iterations = 256, device, "none", 4
        cfg.agent.cuda_graph, cfg.stop_when_solved = graphed, False
        training = Training(cfg, tmp_path / str(graphed))
        initial = [p.detach().clone() for p in training.loop.learner.critic.parameters()]
        torch.manual_seed(1)
        torch.cuda.manual_seed(1)
        training.run()
        learners.append((training.loop.learner, training.loop.records[0].progress.history))
    (graphed, graphed_history), (launched, launched_history) = learners
    assert graphed._graphs is not None and graphed.capturable
    assert launched._graphs is None and not launched.capturable
    assert any(not torch.equal(p, q) for p, q in zip(graphed.critic.parameters(), initial)), "no update ran"
    for ours, theirs in ((graphed.actor, launched.actor), (graphed.critic, launched.critic)):
        for p, q in zip(ours.parameters(), theirs.parameters(), strict=True):  # capturable AdamW rounds otherwise
            torch.testing.assert_close(p, q, rtol=1e-3, atol=1e-4)
    for ours, theirs in zip(graphed_history, launched_history, strict=True):
        assert ours["episodes"] == theirs["episodes"]
        assert ours["mean_return"] == pytest.approx(theirs["mean_return"], rel=1e-4)
