"""SyncFreePPO's update equals rsl-rl's PPO update on the same rollout: same networks, learning rate and losses."""

import copy

import pytest
import torch
from conftest import collect

import cartpole_warp
from cartpole_warp.rl.config import train_config
from cartpole_warp.rl.loop import TrainingLoop
from cartpole_warp.wrappers.rsl_rl import RslRlVecEnv


def runner_for(class_name, schedule="adaptive", torch_compile_mode=None, use_mixed_precision=False,
               obs_normalization=False, symmetry=False):
    cfg = train_config()
    cfg.agent.algorithm.symmetry = symmetry
    cfg.agent.actor.obs_normalization = cfg.agent.critic.obs_normalization = obs_normalization
    cfg.agent.torch_compile_mode, cfg.agent.algorithm.use_mixed_precision = torch_compile_mode, use_mixed_precision
    cfg.env.num_envs = 64
    cfg.agent.algorithm.class_name = class_name
    cfg.agent.algorithm.schedule = schedule
    cfg.agent.algorithm.num_mini_batches = 8
    cfg.agent.algorithm.num_learning_epochs = 3
    torch.manual_seed(0)
    return TrainingLoop(RslRlVecEnv(cartpole_warp.make_env(num_envs=64, seed=3)), cfg, None)


def nudge_actors(*runners):
    """Move every actor's weights by the same small step after its rollout. The adaptive rule raises the learning
    rate only for a KL above 0, and without the nudge some mini-batches' KLs are 0 in exact arithmetic (the policy
    not yet changed, or by a 1e-5 step: 0.0, 2.9e-8 and 7.8e-8 here), so float rounding picks the branch: on an Intel
    Xeon the two updates' learning rates parted in the third update (docs/benchmarks.md). Nudged, every KL is
    above 1e-3 (and below the rule's 0.01)."""
    steps = [0.01 * torch.randn_like(p) for p in runners[0].learner.alg.actor.parameters()]
    with torch.no_grad():
        for runner in runners:
            for param, step in zip(runner.learner.alg.actor.parameters(), steps, strict=True):
                param += step


@pytest.mark.parametrize(("schedule", "symmetry"), [("adaptive", True), ("fixed", True), ("adaptive", False)])
def test_sync_free_update_equals_rsl_rl_update(schedule, symmetry):
    reference, sync_free = runner_for("PPO", schedule, symmetry=symmetry), runner_for("SyncFreePPO", schedule,
                                                                                      symmetry=symmetry)
    assert type(sync_free.learner.alg).__name__ == "SyncFreePPO" and type(reference.learner.alg).__name__ == "PPO"
    assert (reference.learner.alg.symmetry is not None) == (sync_free.learner.alg.symmetry is not None) == symmetry
    sync_free.learner.alg.actor.load_state_dict(reference.learner.alg.actor.state_dict())
    sync_free.learner.alg.critic.load_state_dict(reference.learner.alg.critic.state_dict())
    for _ in range(3):
        torch.manual_seed(1)
        collect(reference)
        sync_free.learner.alg.storage = copy.deepcopy(reference.learner.alg.storage)
        nudge_actors(reference, sync_free)
        torch.manual_seed(2)
        expected = reference.learner.alg.update()
        torch.manual_seed(2)
        got = sync_free.learner.alg.update()
        for name in ("value", "surrogate", "entropy"):
            assert got[name] == pytest.approx(expected[name], rel=1e-4, abs=1e-6), name
        assert sync_free.learner.alg.learning_rate == pytest.approx(reference.learner.alg.learning_rate, rel=1e-5)
        for ours, theirs in zip(sync_free.learner.alg.actor.parameters(), reference.learner.alg.actor.parameters(),
                                strict=True):
            torch.testing.assert_close(ours, theirs, rtol=1e-4, atol=1e-5)
        for ours, theirs in zip(sync_free.learner.alg.critic.parameters(), reference.learner.alg.critic.parameters(),
                                strict=True):
            torch.testing.assert_close(ours, theirs, rtol=1e-4, atol=1e-5)
    if schedule == "adaptive":
        assert reference.learner.alg.learning_rate != 1e-3, ("the adaptive rule must have acted for the test to mean "
                                                             "something")


def test_observation_statistics_stay_in_the_tensors_the_graphs_read():
    """With observation normalisation, SyncFreePPO's update leaves the normalizers' mean and std in the tensors they
    started in (captured CUDA graphs read those), holding the statistics of every observation seen."""
    runner = runner_for("SyncFreePPO", obs_normalization=True)
    normalizers = [runner.learner.alg.actor.obs_normalizer, runner.learner.alg.critic.obs_normalizer]
    tensors = [(n._mean, n._std) for n in normalizers]
    seen = []
    for _ in range(2):
        collect(runner)
        seen.append(runner.learner.alg.storage.observations["policy"].flatten(0, 1).clone())
        runner.learner.alg.update()
    seen = torch.cat(seen)
    for normalizer, (mean, std) in zip(normalizers, tensors, strict=True):
        assert normalizer._mean is mean and normalizer._std is std
        torch.testing.assert_close(std[0], seen.std(dim=0, unbiased=False), rtol=1e-4, atol=1e-6)
        torch.testing.assert_close(mean[0], seen.mean(dim=0), rtol=1e-4, atol=1e-6)


def test_sync_free_ppo_loads_a_ppo_checkpoint_and_keeps_its_rate_tensor(tmp_path):
    reference, sync_free = runner_for("PPO"), runner_for("SyncFreePPO")
    collect(reference)
    reference.learner.alg.update()
    reference.records[0].save(str(tmp_path / "model_0.pt"))
    sync_free.records[0].load(str(tmp_path / "model_0.pt"))
    assert sync_free.learner.alg.learning_rate == pytest.approx(reference.learner.alg.learning_rate)
    assert sync_free.learner.alg.optimizer.param_groups[0]["lr"] is sync_free.learner.alg._learning_rate
    collect(sync_free)
    sync_free.learner.alg.update()


def test_sync_free_gaussian_samples_the_same_distribution():
    from rsl_rl.modules.distribution import GaussianDistribution

    from cartpole_warp.rl.policies import SyncFreeGaussian

    torch.manual_seed(0)
    ours, theirs = SyncFreeGaussian(1, init_std=0.7), GaussianDistribution(1, init_std=0.7)
    mean = torch.full((200_000, 1), 0.3)
    ours.update(mean)
    theirs.update(mean)
    samples = ours.sample()
    assert samples.mean().item() == pytest.approx(0.3, abs=0.01)
    assert samples.std().item() == pytest.approx(0.7, rel=0.01)
    torch.testing.assert_close(ours.log_prob(samples), theirs.log_prob(samples))
    assert ours.sample().shape == theirs.sample().shape == (200_000, 1)


def test_sync_free_ppo_samples_with_the_sync_free_gaussian():
    from cartpole_warp.rl.policies import SyncFreeGaussian

    assert isinstance(runner_for("SyncFreePPO").learner.alg.actor.distribution, SyncFreeGaussian)


def test_rsl_rl_compile_and_mixed_precision_options_reach_its_ppo():
    compiled = runner_for("SyncFreePPO", torch_compile_mode="default")
    assert isinstance(compiled.learner.alg.actor, torch._dynamo.eval_frame.OptimizedModule)
    assert isinstance(compiled.learner.alg.critic, torch._dynamo.eval_frame.OptimizedModule)
    assert not isinstance(runner_for("SyncFreePPO").learner.alg.actor, torch._dynamo.eval_frame.OptimizedModule)
    mixed = runner_for("SyncFreePPO", use_mixed_precision=True)
    assert mixed.learner.alg.use_mixed_precision
    collect(mixed)
    losses = mixed.learner.alg.update()
    assert all(torch.isfinite(torch.tensor(v)) for v in losses.values()), losses
