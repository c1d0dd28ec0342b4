"""PopulationPPO: each member's rollout, returns and update equal rsl-rl's own ``PPO`` fed that member's data (same
actions, rewards, dones, time-outs and mini-batch permutation), MLP actors and actors that see camera frames
(``ImageModel``) alike; members do not affect each other; an inactive member stays as it was."""

from cartpole_warp.wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
from types import SimpleNamespace

import pytest
import torch
from rsl_rl.algorithms import PPO
from rsl_rl.models import MLPModel
from rsl_rl.storage import RolloutStorage
from tensordict import TensorDict

from cartpole_warp.rl.image_model import ImageModel
from cartpole_warp.rl.learners.batched_ppo.update import BatchedActorCritic, PopulationPPO
from cartpole_warp.wrappers.rsl_rl import mirror

NUM_OBS, NUM_ACTIONS, NUM_ENVS, NUM_STEPS = 4, 1, 16, 8
EPOCHS = {"num_learning_epochs": 2, "num_mini_batches": 4}
MIRROR_SIGNS = SimpleNamespace(obs_mirror=torch.tensor([-1.0, -1.0, -1.0, -1.0]), action_mirror=torch.tensor([-1.0]))
"""The cartpole's mirror (``RslRlVecEnv.obs_mirror``, ``action_mirror``)."""
CLOSE = {"rtol": 1e-4, "atol": 1e-5}
"""Tolerance of networks and normaliser statistics (as tests/test_ppo.py): float rounding of batched matrix products
and float32 bias corrections against rsl-rl's per-member ones."""
IMAGE_SHAPE = (6, 12, 12)
"""Two stacked colour frames of 12 x 12 pixels (uint8, as the env gives them)."""
IMAGE_CNN = {"output_channels": [4, 4], "kernel_size": [4, 3], "stride": [2, 1], "activation": "elu"}
"""An encoder whose first convolution runs over 2 x 2 pixel blocks (``ImageModel``'s rewrite), then one more."""
THREE_MEMBERS = {"learning_rate": [1e-3, 3e-4, 2e-3], "entropy_coef": [0.01, 0.0, 0.05], "gamma": [0.99, 0.95, 0.9],
                 "lam": [0.95, 0.9, 1.0], "clip_param": [0.2, 0.1, 0.3], "desired_kl": [0.01, 0.005, 0.02],
                 "value_loss_coef": [1.0, 0.5, 2.0], "max_grad_norm": [1.0, 0.3, 2.0]}


@pytest.fixture(autouse=True)
def one_thread():
    """One torch thread for these tiny tensors: two threads on a busy 2-core machine wait on each other (5 s -> 0.1 s
    per test)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def flat_mirror(obs, actions):
    """The population's form of ``mirror``: flat tensors, originals first."""
    return (torch.cat([obs, obs * MIRROR_SIGNS.obs_mirror]), torch.cat([actions, actions * MIRROR_SIGNS.action_mirror]))


def td(obs: torch.Tensor) -> TensorDict:
    return TensorDict({"policy": obs}, batch_size=[obs.shape[0]])


def mlp_models(obs_normalization: bool) -> tuple[MLPModel, MLPModel]:
    """rsl-rl's (actor, critic) as ``rl.policies.to_rsl_rl`` configures them (small)."""
    obs, groups = td(torch.zeros(NUM_ENVS, NUM_OBS)), {"actor": ["policy"], "critic": ["policy"]}
    model = {"hidden_dims": [16, 16], "activation": "elu", "obs_normalization": obs_normalization}
    return (MLPModel(obs, groups, "actor", NUM_ACTIONS, distribution_cfg={"class_name": "GaussianDistribution",
                                                                          "init_std": 0.8}, **model),
            MLPModel(obs, groups, "critic", 1, **model))


def image_obs(images: torch.Tensor, state: torch.Tensor) -> TensorDict:
    """An env's observations where the policy sees frames (``RslRlVecEnv``'s groups)."""
    return TensorDict({"policy": images, "critic": state}, batch_size=[state.shape[0]])


def image_models() -> tuple[ImageModel, MLPModel]:
    """An actor that sees frames and a critic of the state, as ``rl.policies.to_rsl_rl`` configures them (small)."""
    obs = image_obs(torch.zeros(NUM_ENVS, *IMAGE_SHAPE, dtype=torch.uint8), torch.zeros(NUM_ENVS, NUM_OBS))
    groups = {"actor": ["policy"], "critic": ["critic"]}
    actor = ImageModel(obs, groups, "actor", NUM_ACTIONS, hidden_dims=[16], activation="elu", obs_normalization=True,
                       distribution_cfg={"class_name": "GaussianDistribution", "init_std": 0.8}, cnn_cfg=IMAGE_CNN)
    return actor, MLPModel(obs, groups, "critic", 1, hidden_dims=[16, 16], activation="elu", obs_normalization=True)


def rsl_rl_image_ppo(seed: int, **settings) -> PPO:
    """rsl-rl's PPO with ``image_models`` randomly initialised (``seed``)."""
    torch.manual_seed(seed)
    actor, critic = image_models()
    obs = image_obs(torch.zeros(NUM_ENVS, *IMAGE_SHAPE, dtype=torch.uint8), torch.zeros(NUM_ENVS, NUM_OBS))
    return PPO(actor, critic, RolloutStorage("rl", NUM_ENVS, NUM_STEPS, obs, [NUM_ACTIONS]), **EPOCHS, **settings)


def rsl_rl_ppo(seed: int, schedule="adaptive", symmetry=True, obs_normalization=True, **settings) -> PPO:
    """rsl-rl's PPO on randomly initialised networks (``seed``)."""
    torch.manual_seed(seed)
    actor, critic = mlp_models(obs_normalization)
    symmetry_cfg = ({"env": MIRROR_SIGNS, "use_data_augmentation": True, "data_augmentation_func": mirror}
                    if symmetry else None)
    storage = RolloutStorage("rl", NUM_ENVS, NUM_STEPS, td(torch.zeros(NUM_ENVS, NUM_OBS)), [NUM_ACTIONS])
    return PPO(actor, critic, storage, schedule=schedule, symmetry_cfg=symmetry_cfg, **EPOCHS, **settings)


def population_of(references: list[PPO], schedule="adaptive", symmetry=True, **settings) -> PopulationPPO:
    model = BatchedActorCritic.from_members([r.actor for r in references], [r.critic for r in references])
    return PopulationPPO(model, NUM_ENVS, NUM_STEPS, schedule=schedule, mirror=flat_mirror if symmetry else None,
                         **EPOCHS, **settings)


def rollout(population: PopulationPPO, references: list[PPO], data: torch.Generator, images: bool = False
            ) -> tuple[torch.Tensor, torch.Tensor | None]:
    """One rollout of random observations (and frames, where the actors see ``images``), rewards, dones and time-outs
    (from ``data``) through the population and each member's rsl-rl PPO (which samples the population's actions),
    then both compute returns; the last observations (K, N, O) and frames (K, N, C, H, W) out."""
    members = population.model.num_members

    def draw() -> tuple[torch.Tensor, torch.Tensor | None]:
        state = 2.0 * torch.randn(members, NUM_ENVS, NUM_OBS, generator=data) + 0.5
        return state, (torch.randint(0, 256, (members, NUM_ENVS, *IMAGE_SHAPE), generator=data, dtype=torch.uint8)
                       if images else None)

    def seen(obs: tuple[torch.Tensor, torch.Tensor | None], k: int) -> TensorDict:
        return td(obs[0][k]) if obs[1] is None else image_obs(obs[1][k], obs[0][k])

    obs = draw()
    for _ in range(NUM_STEPS):
        actions = population.act(*obs)
        next_obs = draw()
        rewards = torch.randn(members, NUM_ENVS, generator=data)
        dones = torch.rand(members, NUM_ENVS, generator=data) < 0.2
        time_outs = dones & (torch.rand(members, NUM_ENVS, generator=data) < 0.5)
        population.process_env_step(rewards, dones.float(), time_outs.float())
        for k, reference in enumerate(references):
            reference.actor.distribution.sample = lambda sampled=actions[k]: sampled.clone()
            reference.act(seen(obs, k))
            reference.process_env_step(seen(next_obs, k), rewards[k], dones[k].long(), {"time_outs": time_outs[k]})
        obs = next_obs
    population.compute_returns(obs[0])
    for k, reference in enumerate(references):
        del reference.actor.distribution.sample
        reference.compute_returns(seen(obs, k))
        torch.testing.assert_close(population.returns[k], reference.storage.returns.squeeze(-1), **CLOSE)
        torch.testing.assert_close(population.advantages[k], reference.storage.advantages.squeeze(-1), **CLOSE)
    return obs


def nudge_actors(population: PopulationPPO, references: list[PPO], data: torch.Generator):
    """Move each member's actor (ours and rsl-rl's) by the same small random step, so that the adaptive rule's KLs are
    clearly above 0 (tests/test_ppo.py's ``nudge_actors`` says why)."""
    for k, reference in enumerate(references):
        actor_state, critic_state = population.model.member_state_dicts(k)
        with torch.no_grad():
            for name, param in reference.actor.named_parameters():
                step = 0.01 * torch.randn(param.shape, generator=data)
                param += step
                actor_state[name] += step
        population.model.load_member_state_dicts(k, actor_state, critic_state)


def permutations(members: int, seed: int) -> torch.Tensor:
    """Each member's mini-batch permutation, drawn as rsl-rl's ``mini_batch_generator`` draws it after
    ``torch.manual_seed(seed + k)``."""
    batch = EPOCHS["num_mini_batches"] * (NUM_ENVS * NUM_STEPS // EPOCHS["num_mini_batches"])
    drawn = []
    for k in range(members):
        torch.manual_seed(seed + k)
        drawn.append(torch.randperm(batch))
    return torch.stack(drawn)


def update_both(population: PopulationPPO, references: list[PPO], seed: int):
    """Both updates on the same permutations; each member's networks, learning rate and losses must match."""
    got = population.update(permutations(len(references), seed))
    for k, reference in enumerate(references):
        torch.manual_seed(seed + k)
        expected = reference.update()
        for name in ("value", "surrogate", "entropy"):
            assert got[name][k].item() == pytest.approx(expected[name], rel=1e-4, abs=1e-6), (k, name)
        assert population.learning_rate[k].item() == pytest.approx(reference.learning_rate, rel=1e-5), k
        fresh = (image_models() if isinstance(reference.actor, ImageModel)
                 else mlp_models(reference.actor.obs_normalization))
        for ours, theirs, new in zip(population.model.member_state_dicts(k), (reference.actor, reference.critic),
                                     fresh):
            assert list(ours) == list(theirs.state_dict())
            torch.testing.assert_close(ours, theirs.state_dict(), **CLOSE)
            new.load_state_dict(ours)  # an rsl-rl model loads a member's state dict


def train_both(population: PopulationPPO, references: list[PPO], iterations: int = 3, images: bool = False):
    data = torch.Generator().manual_seed(7)
    for iteration in range(iterations):
        torch.manual_seed(100 + iteration)
        rollout(population, references, data, images)
        nudge_actors(population, references, data)
        update_both(population, references, seed=1000 * (iteration + 1))


@pytest.mark.parametrize(("schedule", "symmetry", "obs_normalization"),
                         [("adaptive", True, True), ("fixed", True, True), ("adaptive", False, False)])
def test_one_member_equals_rsl_rl_ppo(schedule, symmetry, obs_normalization):
    references = [rsl_rl_ppo(0, schedule, symmetry, obs_normalization, max_grad_norm=0.5)]
    population = population_of(references, schedule, symmetry, max_grad_norm=0.5)
    train_both(population, references)
    if schedule == "adaptive":
        assert references[0].learning_rate != 1e-3, "the adaptive rule must have acted for the test to mean something"


def test_three_members_each_equal_their_own_rsl_rl_ppo():
    references = [rsl_rl_ppo(seed, **{name: values[seed] for name, values in THREE_MEMBERS.items()})
                  for seed in range(3)]
    population = population_of(references, **THREE_MEMBERS)
    train_both(population, references)
    for reference, initial in zip(references, THREE_MEMBERS["learning_rate"]):
        assert reference.learning_rate != pytest.approx(initial), "the adaptive rule must have acted"


def test_actors_that_see_frames_each_equal_their_own_rsl_rl_ppo():
    """Two members whose actors see uint8 frames (an encoder over pixel blocks) and whose
    critics see the state, each against rsl-rl's PPO with an ``ImageModel`` actor: rollout, returns, update, and the
    deterministic actions the evaluation plays."""
    settings = {name: values[:2] for name, values in THREE_MEMBERS.items()}
    references = [rsl_rl_image_ppo(seed, **{name: values[seed] for name, values in settings.items()})
                  for seed in range(2)]
    population = population_of(references, symmetry=False, **settings)
    assert population.images.dtype == torch.uint8 and population.images.shape[3:] == IMAGE_SHAPE
    train_both(population, references, images=True)
    state, frames = rollout(population, [], torch.Generator().manual_seed(8), images=True)
    for k, reference in enumerate(references):
        reference.actor.eval()
        torch.testing.assert_close(population.model.action_mean(frames)[k],
                                   reference.actor(image_obs(frames[k], state[k])), **CLOSE)
        assert reference.learning_rate != settings["learning_rate"][k], "the adaptive rule must have acted"


def test_a_population_of_image_actors_refuses_what_they_cannot_take():
    actor, critic = image_models()
    model = BatchedActorCritic.from_members([actor], [critic])
    with pytest.raises(ValueError, match="mirrors state observations, not an image actor's frames"):
        PopulationPPO(model, NUM_ENVS, NUM_STEPS, mirror=flat_mirror)
    with pytest.raises(ValueError, match="an image actor needs its images"):
        model(torch.zeros(1, NUM_ENVS, NUM_OBS))


def train_alone(population: PopulationPPO, iterations: int = 2) -> list[dict[str, torch.Tensor]]:
    data, losses = torch.Generator().manual_seed(7), []
    for iteration in range(iterations):
        torch.manual_seed(100 + iteration)
        rollout(population, [], data)
        losses.append(population.update(permutations(population.model.num_members, 1000 * (iteration + 1))))
    return losses


def member(population: PopulationPPO, k: int) -> list[torch.Tensor]:
    """Everything that is member ``k``'s: parameters, normaliser statistics, Adam state, learning rate."""
    model = population.model
    normalizers = [getattr(n, name)[k] for n in (model.actor_normalizer, model.critic_normalizer)
                   for name in ("mean", "var", "std", "count")]
    return [t.clone() for t in (model.params[k].detach(), *normalizers, population.exp_avg[k],
                                population.exp_avg_sq[k], population.adam_steps[k], population.learning_rate[k])]


def test_one_member_does_not_change_another():
    settings = {name: values for name, values in THREE_MEMBERS.items()}
    first = population_of([rsl_rl_ppo(seed) for seed in range(3)], **settings)
    other_lr = settings | {"learning_rate": [5e-3, *settings["learning_rate"][1:]]}
    second = population_of([rsl_rl_ppo(seed) for seed in (9, 1, 2)], **other_lr)
    first_losses, second_losses = train_alone(first), train_alone(second)
    assert not torch.equal(member(first, 0)[0], member(second, 0)[0])
    for k in (1, 2):
        for ours, theirs in zip(member(first, k), member(second, k)):
            assert torch.equal(ours, theirs), k
        for a, b in zip(first_losses, second_losses):
            assert all(torch.equal(a[name][k], b[name][k]) for name in a), k


def test_an_inactive_member_is_left_unchanged():
    population = population_of([rsl_rl_ppo(seed) for seed in range(3)], **THREE_MEMBERS)
    population.active[2] = False  # inactive from the start: no Adam step yet
    before = {2: member(population, 2), 0: member(population, 0)}
    train_alone(population, iterations=1)
    population.active[1] = False  # inactive after an update: Adam moments held
    before[1] = member(population, 1)
    train_alone(population, iterations=1)
    for k in (1, 2):
        for ours, theirs in zip(member(population, k), before[k]):
            assert torch.equal(ours, theirs), k
    assert not torch.equal(member(population, 0)[0], before[0][0])
    assert torch.isfinite(population.model.params).all()


def test_the_batched_model_refuses_networks_it_does_not_batch():
    actor, critic = mlp_models(obs_normalization=False)
    image_actor, _ = image_models()
    with pytest.raises(ValueError, match="the critic must be an rsl-rl MLPModel, not ImageModel"):
        BatchedActorCritic(actor, image_actor, 1)
    with pytest.raises(ValueError, match="the actor must be an rsl-rl MLPModel or an ImageModel, not Linear"):
        BatchedActorCritic(torch.nn.Linear(1, 1), critic, 1)
