"""The leader and followers (``--learner sapg``, ``rl.learners.sapg``): the leader's update against its definition (with
no weight on the followers it is PPO's, a follower that acts as the leader gives importance weights of 1, and its loss
on a follower's samples is computed here from rsl-rl's own networks), the learner's settings and refusals, a run on
every state task, the same run from the same seed, a resumed run, and the balance trained to solved and played by
``play.py --headless``."""

from cartpole_warp.wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
import json

import pytest
import torch
from conftest import DEVICE, call_main
from rsl_rl.models import MLPModel
from test_population_ppo import EPOCHS, NUM_ENVS, NUM_STEPS, mlp_models, one_thread, permutations, rollout, rsl_rl_ppo
from test_train_cli import only_run, train_to_solved_and_play

from cartpole_warp import tasks
from cartpole_warp.rl.config import train_config
from cartpole_warp.rl.learners.batched_ppo.update import BatchedActorCritic, PopulationPPO, gaussian_log_prob
from cartpole_warp.rl.learners.sapg.learner import LeaderFollowerPPO

STATE_TASKS = [name for name in tasks.names() if not train_config(name).env.camera.enabled]
SETTINGS = {"gamma": 0.95, "clip_param": 0.2, "value_loss_coef": 0.5, "entropy_coef": 0.01}
__all__ = ["one_thread"]  # the fixture (autouse) of tests/test_population_ppo.py: one torch thread


def leader_and_followers(seeds, ppo_class=LeaderFollowerPPO, **settings):
    """A population of rsl-rl networks initialised with ``seeds`` (member 0 the leader), without symmetry."""
    references = [rsl_rl_ppo(seed, symmetry=False) for seed in seeds]
    model = BatchedActorCritic.from_members([r.actor for r in references], [r.critic for r in references])
    return ppo_class(model, NUM_ENVS, NUM_STEPS, **EPOCHS, **SETTINGS, **settings)


def losses_passed_to_the_step(monkeypatch, ppo: PopulationPPO, permutation: torch.Tensor) -> list[torch.Tensor]:
    """``ppo.update(permutation)``, recording each mini-batch's (K,) loss as it reaches the Adam step."""
    seen = []
    step = PopulationPPO._step

    def recording(self, loss, mini_batch):
        seen.append(loss.detach().clone())
        step(self, loss, mini_batch)

    monkeypatch.setattr(PopulationPPO, "_step", recording)
    ppo.update(permutation)
    monkeypatch.undo()
    return seen


def test_with_no_weight_on_the_followers_every_member_learns_as_population_ppo():
    """``off_policy_coef`` 0: every member's networks and optimiser state after two iterations are PopulationPPO's
    (whose members tests/test_population_ppo.py checks against rsl-rl's PPO)."""
    leader = leader_and_followers([0, 1, 2], off_policy_coef=0.0)
    plain = leader_and_followers([0, 1, 2], ppo_class=PopulationPPO)
    for ppo in (leader, plain):
        data = torch.Generator().manual_seed(7)
        for iteration in range(2):
            torch.manual_seed(100 + iteration)
            rollout(ppo, [], data)
            ppo.update(permutations(3, 1000 * (iteration + 1)))
    torch.testing.assert_close(leader.model.params, plain.model.params, rtol=0, atol=0)
    torch.testing.assert_close(leader.exp_avg_sq, plain.exp_avg_sq, rtol=0, atol=0)
    assert not torch.equal(leader.model.params[0], leader.model.params[1])


def test_a_follower_that_acts_as_the_leader_has_importance_weights_of_one():
    """A follower with the leader's networks: the leader's log-probabilities of the follower's actions are the ones
    the follower stored (ratio 1), and the values the leader gives the follower's states are the follower's own."""
    ppo = leader_and_followers([0, 0])
    torch.manual_seed(3)
    rollout(ppo, [], torch.Generator().manual_seed(7))
    assert ppo.follower.item() == 1
    obs, actions, values, _, _, log_prob, _, _ = (t.flatten(0, 1) for t in ppo.off_policy.split(ppo._fields, -1))
    mean, std, _ = ppo.model(obs[None], ppo.leader_index)
    ratio = torch.exp(gaussian_log_prob(actions[None], mean, std) - log_prob.squeeze(-1))
    torch.testing.assert_close(ratio, torch.ones_like(ratio), rtol=0, atol=1e-6)
    torch.testing.assert_close(values.squeeze(-1), ppo.values[1].flatten(), rtol=0, atol=1e-6)


def leaders_networks(ppo: LeaderFollowerPPO) -> tuple[MLPModel, MLPModel, torch.Tensor]:
    """rsl-rl's (actor, critic) holding the leader's weights and normalisers, in eval mode, and its action std."""
    actor, critic = mlp_models(obs_normalization=True)
    actor_state, critic_state = ppo.model.member_state_dicts(0)
    for network, state in ((actor, actor_state), (critic, critic_state)):
        network.load_state_dict(state)
        network.eval()
    return actor, critic, actor_state["distribution.std_param"]


def copy_state(source: PopulationPPO, target: PopulationPPO):
    """``target`` made to hold ``source``'s networks, normalisers, optimiser state and rollout."""
    target.model.load_state_dict(source.model.state_dict())
    for name in ("exp_avg", "exp_avg_sq", "adam_steps", "learning_rate", "rollout", "rewards", "dones"):
        getattr(target, name).copy_(getattr(source, name))


def second_iteration(dual_clip=None, coef=0.7) -> tuple[LeaderFollowerPPO, PopulationPPO, torch.Tensor]:
    """A leader and two followers after one iteration and the rollout of a second (the normalisers no longer at their
    start, each member's its own), and a PopulationPPO holding the same state; the last observations."""
    ppo = leader_and_followers([0, 1, 2], off_policy_coef=coef, dual_clip=dual_clip)
    data = torch.Generator().manual_seed(11)
    torch.manual_seed(5)
    rollout(ppo, [], data)
    ppo.update(permutations(3, 8))
    last_obs, _ = rollout(ppo, [], data)
    plain = leader_and_followers([0, 1, 2], ppo_class=PopulationPPO)
    copy_state(ppo, plain)
    return ppo, plain, last_obs


@pytest.mark.parametrize("dual_clip", [None, 1.25])
def test_the_leaders_loss_on_a_followers_samples_is_its_definition(monkeypatch, dual_clip):
    """The leader's first mini-batch loss minus its PPO loss equals ``off_policy_coef`` (L_surrogate + value_loss_coef
    L_value) of the follower's samples, computed here with rsl-rl's networks holding the leader's weights and
    normalisers: one-step targets r + gamma (1 - done) V(s'), advantages normalised over the rollout, the ratio to the
    follower's stored probabilities clipped (and dual-clipped); the followers' losses are their PPO losses alone."""
    coef = 0.7
    ppo, plain, last_obs = second_iteration(dual_clip, coef)
    j = ppo.follower.item()
    assert j in (1, 2)
    normalizer = ppo.model.critic_normalizer
    assert not torch.equal(normalizer.mean[0], normalizer.mean[j]), "the leader's normaliser must be its own"
    actor, critic, std = leaders_networks(ppo)
    obs, actions = ppo.observations[j].flatten(0, 1), ppo.actions[j].flatten(0, 1)
    with torch.no_grad():
        values = critic({"policy": obs}).view(NUM_STEPS, NUM_ENVS)
        next_values = torch.cat((values[1:], critic({"policy": last_obs[j]}).view(1, NUM_ENVS)))
    targets = ppo.rewards[j] + SETTINGS["gamma"] * (1 - ppo.dones[j]) * next_values
    advantages = targets - values
    advantages = ((advantages - advantages.mean()) / (advantages.std() + 1e-8)).flatten()

    with_off_policy = losses_passed_to_the_step(monkeypatch, ppo, permutations(3, 9))
    alone = losses_passed_to_the_step(monkeypatch, plain, permutations(3, 9))
    rows = ppo._off_permutation[:NUM_ENVS * NUM_STEPS // EPOCHS["num_mini_batches"]]
    with torch.no_grad():
        log_prob = torch.distributions.Normal(actor({"policy": obs[rows]}), std).log_prob(actions[rows]).sum(-1)
        value_loss = (critic({"policy": obs[rows]}).squeeze(-1) - targets.flatten()[rows]).pow(2).mean()
    ratio = torch.exp(log_prob - ppo.actions_log_prob[j].flatten()[rows])
    advantage = advantages[rows]
    surrogate = torch.max(-advantage * ratio, -advantage * ratio.clamp(0.8, 1.2))
    if dual_clip is not None:
        surrogate = torch.where(advantage < 0, torch.min(surrogate, -dual_clip * advantage), surrogate)
    expected = coef * (surrogate.mean() + SETTINGS["value_loss_coef"] * value_loss)
    torch.testing.assert_close(with_off_policy[0][0] - alone[0][0], expected, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(with_off_policy[0][1:], alone[0][1:], rtol=0, atol=0)
    assert (ratio - 1).abs().max() > 0.2, "the follower's policy differs from the leader's: the clip must act"
    if dual_clip is not None:
        assert (surrogate == -dual_clip * advantage).any(), "the dual clip must act for the test to mean something"


def test_every_epoch_takes_each_of_the_followers_samples_once_in_mini_batches(monkeypatch):
    """The leader's batches of the follower's samples: per epoch a partition of all T x N of them, the same in each
    epoch, one per mini-batch; the off-policy losses come back with the update's, the leader's alone."""
    ppo, _, _ = second_iteration()
    batches = []
    losses = PopulationPPO._losses

    def recording(self, batch, members=None, dual_clip=None, images=None):
        if members is not None:
            batches.append(batch[0].clone())
        return losses(self, batch, members, dual_clip, images)

    monkeypatch.setattr(PopulationPPO, "_losses", recording)
    reported = ppo.update(permutations(3, 9))
    samples = ppo.off_policy.flatten(0, 1)
    per_epoch = EPOCHS["num_mini_batches"]
    assert len(batches) == EPOCHS["num_learning_epochs"] * per_epoch
    first = torch.cat(batches[:per_epoch])
    assert torch.equal(first, torch.cat(batches[per_epoch:])), "the same mini-batches in every epoch"
    order = lambda rows: rows[torch.argsort(rows[:, 0])]  # noqa: E731  (rows sorted by their first observation)
    assert torch.equal(order(first), order(samples)), "every sample once per epoch"
    assert reported["off_policy_value"][0] > 0 and reported["off_policy_value"][1:].eq(0).all()
    assert reported["off_policy_surrogate"][1:].eq(0).all()


def test_only_the_leader_learns_from_the_follower_and_every_follower_is_drawn():
    """One update with and without weight on the follower's samples, from the same state: the leader's parameters
    differ, the followers' are bitwise the same (the loss reaches the leader's gradient and no other); over iterations
    the follower is drawn among all of 1 .. K-1."""
    ppo, plain, _ = second_iteration(coef=0.7)
    unweighted = leader_and_followers([0, 1, 2], off_policy_coef=0.0)
    copy_state(ppo, unweighted)
    unweighted.off_policy.copy_(ppo.off_policy)
    unweighted.follower.copy_(ppo.follower)
    for learner in (ppo, unweighted):
        torch.manual_seed(1)
        learner.update(permutations(3, 9))
    assert not torch.equal(ppo.model.params[0], unweighted.model.params[0])
    assert torch.equal(ppo.model.params[1:], unweighted.model.params[1:])
    drawn = set()
    four = leader_and_followers([0, 1, 2, 3])
    data = torch.Generator().manual_seed(2)
    for _ in range(30):
        rollout(four, [], data)
        drawn.add(four.follower.item())
        four.step = 0
    assert drawn == {1, 2, 3}


def small_training(tmp_path):
    """A sapg run of 4 blocks of 8 envs, 4 steps per env, on the CPU, built in this process."""
    from cartpole_warp.rl.training import Training

    cfg = train_config(learner="sapg")
    cfg.env.num_envs, cfg.env.device, cfg.agent.num_steps_per_env, cfg.agent.logger = 8, "cpu", 4, "none"
    return Training(cfg, tmp_path)


def test_the_best_policy_loaded_for_the_exports_is_the_leaders_and_the_followers_stay(tmp_path):
    """The run's end loads ``model_best.pt``'s actor (``load_cfg`` {"actor": True}) before it exports: the leader's
    rsl-rl actor, which the exports hold, is then that checkpoint's, its critic and the followers as they were."""
    learner = small_training(tmp_path).loop.learner
    obs, _ = learner.iteration(learner.batched.env.get_observations(), 0)
    best = learner.state_dict()
    learner.iteration(obs, 1)
    ppo = learner.batched.ppo
    params, critic = ppo.model.params.detach().clone(), ppo.model.member_state_dicts(0)[1]
    learner.load_state_dict(best, {"actor": True}, strict=True)
    for key, value in best["actor_state_dict"].items():
        torch.testing.assert_close(learner.actor.state_dict()[key], value, rtol=0, atol=0)
    assert not torch.equal(ppo.model.params[0], params[0]), "the leader had moved on since the best"
    assert torch.equal(ppo.model.params[1:], params[1:])
    torch.testing.assert_close(ppo.model.member_state_dicts(0)[1], critic, rtol=0, atol=0)


def test_a_follower_gone_non_finite_starts_again_from_the_leader(tmp_path, monkeypatch, capsys):
    """A follower whose update left non-finite weights takes the leader's networks, optimiser state and learning rate
    before the next iteration could feed its samples to the leader; a line names it."""
    learner = small_training(tmp_path).loop.learner
    population, ppo = learner.batched, learner.batched.ppo
    iteration = population.iteration

    def diverging(obs, it):
        result = iteration(obs, it)
        ppo.model.params.data[2] = float("nan")
        return result

    monkeypatch.setattr(population, "iteration", diverging)
    learner.iteration(learner.batched.env.get_observations(), 0)
    assert torch.isfinite(ppo.model.params).all()
    for tensor in (ppo.model.params, ppo.exp_avg, ppo.exp_avg_sq, ppo.learning_rate, ppo.adam_steps):
        assert torch.equal(tensor[2], tensor[0])
    assert not torch.equal(ppo.model.params[1], ppo.model.params[0])
    assert "follower 2's networks went non-finite in iteration 1: it starts again from the leader's" in \
        capsys.readouterr().out


def test_the_console_line_counts_the_leaders_envs(tmp_path, capsys):
    """The console line is the leader's: an iteration in which none of its episodes ended counts its block's 8 envs,
    not the run's 32."""
    small_training(tmp_path).loop.learn(1)
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("it ")]
    assert len(rows) == 1 and "no episode ended; 8 running," in rows[0], rows


def sapg_run(tmp_path, *flags, task=tasks.DEFAULT_TASK, iterations=2):
    """train.py --learner sapg with blocks of 8 envs and 4 steps per env, on the CPU."""
    return call_main("train", "--task", task, "--learner", "sapg", "--num-envs", "8", "--agent.num-steps-per-env",
                     "4", "--device", "cpu", "--logger", "none", "--log-dir", tmp_path, "--no-stop-when-solved",
                     "--max-iterations", iterations, *flags)


@pytest.mark.parametrize("task", STATE_TASKS)
def test_every_state_task_trains_with_a_leader_and_followers(tmp_path, task):
    """Two iterations: every block's env steps counted, the leader's checkpoint an rsl-rl checkpoint that play.py's
    networks load, with every policy's state besides, each policy having taken its Adam steps."""
    result = sapg_run(tmp_path, task=task)
    assert result.returncode == 0, result.stdout + result.stderr
    run = only_run(tmp_path, task)
    summary = json.loads((run / "summary.json").read_text())
    cfg = train_config(task, learner="sapg")
    blocks, algorithm = cfg.agent.sapg.num_blocks, cfg.agent.algorithm
    assert summary["iterations"] == 2 and summary["env_steps"] == 2 * blocks * 8 * 4, summary
    checkpoint = torch.load(run / "model_1.pt", weights_only=False)
    state = checkpoint["sapg_state_dict"]
    assert state["model"]["params"].shape[0] == blocks and torch.isfinite(state["model"]["params"]).all()
    steps = 2 * algorithm.num_learning_epochs * algorithm.num_mini_batches
    assert state["adam_steps"].tolist() == [steps] * blocks, "every policy took its Adam steps"


def test_a_leader_evaluates_inside_the_step_where_the_task_does():
    """The three poles evaluate inside the training's step on a GPU, with either learner."""
    for learner in ("ppo", "sapg"):
        cfg = train_config("cart-three-pole-swingup", device="cuda:0", learner=learner)
        assert cfg.agent.learner == learner and cfg.eval.in_step


def test_the_evaluation_inside_the_step_plays_the_leader_and_leaves_every_block_as_without_it(tmp_path):
    """Three iterations of the same seed with and without ``eval.in_step`` (an evaluation due after every iteration, so
    its envs restart after the first and step beside the blocks): every block's third rollout and every policy's
    networks are the same; the evaluation's frozen policy is the leader's of the iteration it names. On a GPU
    (``CARTPOLE_TEST_DEVICE``) the rollouts run in the population's CUDA graph, the evaluation's envs inside it."""
    from cartpole_warp.rl.training import Training

    populations = []
    for in_step in (False, True):
        cfg = train_config(learner="sapg")
        cfg.env.num_envs, cfg.env.device, cfg.agent.num_steps_per_env, cfg.agent.logger = 8, DEVICE, 4, "none"
        cfg.eval.num_envs, cfg.eval.in_step, cfg.eval.min_interval, cfg.eval.max_interval = 8, in_step, 1, 1
        runner = Training(cfg, tmp_path / f"run{in_step}").loop
        assert (runner.env.evaluation is not None) == in_step and runner.env.num_envs == 4 * 8
        runner.learn(3)
        populations.append(runner.learner.batched)
    ppos = [population.ppo for population in populations]
    for field in ("observations", "actions", "rewards", "dones"):
        assert torch.equal(*(getattr(ppo, field) for ppo in ppos)), field
    assert torch.equal(ppos[0].model.params, ppos[1].model.params)
    judge = runner.evaluations.in_step
    assert judge.judged_policy is not None, "an evaluation began"
    ppos[1].model.load_state_dict(judge.judged_policy[2]["sapg_state_dict"]["model"])  # the policies it judged
    frozen = judge.frozen_actor.state_dict()
    for member, same in ((0, True), (1, False)):
        actor = ppos[1].model.member_state_dicts(member)[0]
        assert all(torch.equal(frozen[key], actor[key]) for key in actor) == same, member


def test_the_same_seed_trains_the_same_run_and_a_resumed_run_continues_every_policy(tmp_path):
    """Two runs of seed 3 hold the same weights after two iterations (another seed does not); the first resumed for
    one more iteration continues every policy's Adam steps."""
    for name, seed in (("first", 3), ("again", 3), ("other", 4)):
        result = sapg_run(tmp_path / name, "--seed", seed)
        assert result.returncode == 0, result.stdout + result.stderr
    first, again, other = (torch.load(only_run(tmp_path / name) / "model_1.pt", weights_only=False)["sapg_state_dict"]
                           for name in ("first", "again", "other"))
    assert torch.equal(first["model"]["params"], again["model"]["params"])
    assert torch.equal(first["exp_avg_sq"], again["exp_avg_sq"])
    assert not torch.equal(first["model"]["params"], other["model"]["params"])
    run = only_run(tmp_path / "first")
    result = call_main("train", "--resume", run, "--max-iterations", "1", "--device", "cpu", "--logger", "none",
                       "--log-dir", tmp_path / "first", "--no-stop-when-solved")
    assert result.returncode == 0, result.stdout + result.stderr
    resumed = torch.load(run / "model_2.pt", weights_only=False)
    algorithm = train_config().agent.algorithm
    steps = algorithm.num_learning_epochs * algorithm.num_mini_batches
    assert resumed["iter"] == 2
    assert resumed["sapg_state_dict"]["adam_steps"].tolist() == [3 * steps] * 4
    assert not torch.equal(resumed["sapg_state_dict"]["model"]["params"], first["model"]["params"])


@pytest.mark.parametrize(("flags", "message"), [
    (["--task", "cartpole-balance-rgb"], "a task that observes camera frames"),
    (["--agent.sapg.follower-entropy-coefs", "0.1"], "--agent.sapg.follower-entropy-coefs: 1 given for 3 followers"),
    (["--console", "rsl_rl"], "console rsl_rl"),
    (["--agent.sapg.num-blocks", "1"], "--agent.sapg.num-blocks"),
])
def test_what_the_learner_cannot_train_is_one_clear_error(tmp_path, flags, message):
    result = sapg_run(tmp_path, *flags, iterations=1)
    assert result.returncode == 2 and message in result.stderr, result.stdout + result.stderr
    assert "Traceback" not in result.stderr and len(result.stderr.strip().splitlines()) == 1, result.stderr


@pytest.mark.slow
def test_the_balance_trains_to_solved_by_a_leader_and_followers_and_plays(tmp_path):
    """Blocks of 256 envs on the balance: solved (the same rule, the same evaluation of the leader) and replayed by
    play.py from the run's model_best.pt."""
    summary, played = train_to_solved_and_play(tmp_path, "cartpole-balance", "--learner", "sapg", "--num-envs", "256")
    assert summary["num_envs"] == 4 * 256
    assert played["time_limit_fraction"] >= 0.95
