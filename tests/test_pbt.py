"""Population-based training (``--population.exploit-interval``, ``rl.modes.Exploitation``): an exploit copies exactly
a member's whole training state over another's and leaves every other member bitwise unchanged; the bottom member
takes a top one's state and perturbs its settings by the factor, its lineage in its folder and members.md, its folder
playing and resuming with the settings it trains with since; the same seed trains the same population."""

import json

import pytest
import torch
import yaml
from conftest import DEVICE, call_main
from test_train_cli import only_run

from cartpole_warp.rl.config import train_config
from cartpole_warp.rl.modes import Exploitation
from cartpole_warp.rl.population import members_of
from cartpole_warp.rl.runs import CONFIG_FILE, LINEAGE_FILE, MEMBERS_FILE, POPULATION_FILE
from cartpole_warp.rl.training import Training

SETTINGS = ("learning_rate", "entropy_coef", "gamma", "lam", "clip_param", "desired_kl", "value_loss_coef",
            "max_grad_norm")
"""rsl-rl PPO's settings a population's member trains with (``agent.algorithm``)."""


def pbt_population(tmp_path, seeds, modes=(), vary=(), max_iterations=1, num_envs=16):
    cfg = train_config()
    cfg.env.num_envs, cfg.env.device, cfg.agent.logger = num_envs, DEVICE, "none"
    cfg.agent.max_iterations = max_iterations
    cfg.agent.actor.obs_normalization = cfg.agent.critic.obs_normalization = True
    return Training(cfg, tmp_path, members=members_of(list(seeds), list(vary)), modes=list(modes))


def every_tensor(ppo) -> dict[str, torch.Tensor]:
    """Copies of every per-member tensor of the batched PPO, by name, member on the first axis."""
    model = ppo.model
    tensors = {"params": model.params.detach(), "exp_avg": ppo.exp_avg, "exp_avg_sq": ppo.exp_avg_sq,
               "adam_steps": ppo.adam_steps}
    for role, normalizer in (("actor", model.actor_normalizer), ("critic", model.critic_normalizer)):
        tensors |= {f"{role}.{name}": buffer for name, buffer in normalizer.named_buffers()}
    tensors |= {name: getattr(ppo, name) for name in SETTINGS}
    return {name: tensor.clone() for name, tensor in tensors.items()}


def test_an_exploit_copies_exactly_one_members_state_over_another_and_leaves_the_others_bitwise_unchanged(tmp_path):
    """Four members differing in seed and learning rate, after two iterations (their networks, Adam moments and
    steps, normalisers and adapted learning rates all differ): member 1's state over member 3's. Member 3 is then
    member 1 bitwise, in every tensor and in rsl-rl's checkpoint format; members 0, 1 and 2 are bitwise as before."""
    training = pbt_population(tmp_path, [0, 1], vary=["agent.algorithm.learning-rate=1e-3,3e-4"])
    learner = training.loop.learner
    obs = training.env.get_observations()
    for it in range(2):
        obs, _ = learner.iteration(obs, it)
    ppo = learner.ppo
    for k in range(4):  # every per-member number apart, so that a copy that missed one would show
        learner.set_member_settings(k, {name: value * (1 - 0.05 * k) for name, value in
                                        learner.member_settings(k).items()})
        ppo.adam_steps[k] += k
        ppo.model.actor_normalizer.count[k] += k
        ppo.model.critic_normalizer.count[k] += 2 * k
    before = every_tensor(ppo)
    assert all(not torch.equal(tensor[1], tensor[3]) for tensor in before.values()), "members 1 and 3 differ"
    learner.exploit(1, 3)
    after = every_tensor(learner.ppo)
    for name, tensor in after.items():
        assert torch.equal(tensor[3], before[name][1]), name
        for k in (0, 1, 2):
            assert torch.equal(tensor[k], before[name][k]), (name, k)
    source, target = learner.state_dict(1), learner.state_dict(3)
    for part in ("actor_state_dict", "critic_state_dict"):
        assert all(torch.equal(source[part][key], value) for key, value in target[part].items()), part
    for i, state in target["optimizer_state_dict"]["state"].items():
        assert all(torch.equal(source["optimizer_state_dict"]["state"][i][key], value) for key, value in state.items())
    assert learner.member_settings(3) == learner.member_settings(1)


def test_the_bottom_member_takes_a_top_ones_state_perturbs_its_settings_and_its_folder_plays_and_resumes_with_them(
        tmp_path, monkeypatch):
    """Four members, scores fixed (seed1 best, seed0 worst): after iterations 2 and 4 seed0 (the bottom quarter) takes
    seed1's state (the top quarter); its settings are then seed1's, each perturbed one scaled by 1.2 or 1/1.2 (gamma
    and lam in their horizon 1 - x), the learning rate (the adaptive schedule's) seed1's as it stood. Its lineage is
    in lineage.json and members.md, its config.yaml holds the settings, and its folder plays and resumes with them."""
    scores = {0: 1.0, 1: 4.0, 2: 3.0, 3: 2.0}
    monkeypatch.setattr(Exploitation, "scores", lambda self, loop, members: {k: scores[k] for k in members})
    training = pbt_population(tmp_path, [0, 1, 2, 3], [Exploitation(interval=2, seed=3)], max_iterations=4)
    learner, taken = training.loop.learner, []
    exploit = learner.exploit

    def recorded(source, target):
        taken.append((source, target, learner.member_settings(source)))
        exploit(source, target)

    monkeypatch.setattr(learner, "exploit", recorded)
    result = training.run()
    assert [(source, target) for source, target, _ in taken] == [(1, 0), (1, 0)]
    lineage = json.loads((tmp_path / "seed0" / LINEAGE_FILE).read_text())
    assert [(entry["iteration"], entry["took"]) for entry in lineage] == [(2, "seed1"), (4, "seed1")]
    for entry, (_, _, source) in zip(lineage, taken):
        assert entry["scores"] == {"took": 4.0, "own": 1.0}
        assert entry["settings"]["learning_rate"] == pytest.approx(source["learning_rate"], rel=1e-6)
        for name in SETTINGS[1:]:
            horizon = name in ("gamma", "lam")
            ratio = ((1 - entry["settings"][name]) / (1 - source[name]) if horizon
                     else entry["settings"][name] / source[name])
            assert min(abs(ratio - 1.2), abs(ratio - 1 / 1.2)) < 1e-5, (name, ratio)
    assert not (tmp_path / "seed1" / LINEAGE_FILE).exists()
    assert result["exploitation"]["exploits"] == 2
    assert [[tuple(entry) for entry in row["lineage"]] for row in result["members"]] == [
        [(2, "seed1"), (4, "seed1")], [], [], []]
    assert "| seed1 at 2, seed1 at 4 |" in (tmp_path / MEMBERS_FILE).read_text()
    saved = yaml.safe_load((tmp_path / "seed0" / CONFIG_FILE).read_text())["agent"]["algorithm"]
    assert all(saved[name] == pytest.approx(lineage[-1]["settings"][name], rel=1e-6) for name in SETTINGS)
    live = learner.member_settings(0)  # the last exploit came after the last update
    assert all(live[name] == pytest.approx(lineage[-1]["settings"][name], rel=1e-6) for name in SETTINGS)
    last = torch.load(tmp_path / "seed0" / "model_3.pt", weights_only=False)
    actor, _ = learner.ppo.model.member_state_dicts(0)
    assert all(torch.equal(last["actor_state_dict"][key], value) for key, value in actor.items()), (
        "the checkpoint of the exploit's iteration holds the state taken")
    member = tmp_path / "seed0"
    played = call_main("play", "--headless", "--run", member, "--num-envs", "4", "--video-length", "2")
    assert played.returncode == 0, played.stdout + played.stderr
    resumed = call_main("train", "--resume", member, "--max-iterations", "1", "--device", "cpu", "--logger", "none")
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert yaml.safe_load((member / CONFIG_FILE).read_text())["agent"]["algorithm"]["gamma"] == pytest.approx(
        lineage[-1]["settings"]["gamma"], rel=1e-6), "the resumed run trained with the member's settings"


def test_the_same_seed_trains_the_same_pbt_population(tmp_path):
    """Two PBT populations of one seed (real scores: the members' training returns), on one machine: the same
    exploits, the same networks after them."""
    runs = []
    for name in ("a", "b"):
        training = pbt_population(tmp_path / name, [0, 1, 2], [Exploitation(interval=2, fraction=0.34, seed=5)],
                                  max_iterations=6)
        result = training.run()
        runs.append((training.loop.modes[0].events, training.loop.learner.ppo.model.params.detach().clone(), result))
    (events, params, result), (other_events, other_params, _) = runs
    assert events and events == other_events, "exploits happened, the same in both"
    assert torch.equal(params, other_params)
    assert json.loads((tmp_path / "a" / POPULATION_FILE).read_text())["exploitation"]["exploits"] == len(events)


@pytest.mark.parametrize(("flags", "message"), [
    (["--seeds", "0", "--population.exploit-interval", "5"],
     "--population.exploit-interval compares a population's members: give two or more (--seeds 0 1 ...)"),
    (["--seeds", "0", "--population.until", "first-solved"],
     "--population.until first-solved compares a population's members: give two or more"),
    (["--seeds", "0", "1", "--population.exploit-interval", "0"],
     "--population.exploit-interval 0: members exploit every N >= 1 iterations"),
    (["--population.exploit-interval", "5"],
     "--population.exploit-interval: population-based training trains a population: give --seeds"),
    (["--population.perturb-factor", "1.5"],
     "--population.perturb-factor: population-based training trains a population: give --seeds"),
    (["--seeds", "0", "1", "--population.exploit-fraction", "0.25"],
     "--population.exploit-fraction set population-based training: give --population.exploit-interval N too"),
    (["--seeds", "0", "1", "--population.exploit-fraction", "0.5"],
     "--population.exploit-fraction set population-based training: give --population.exploit-interval N too"),
    (["--seeds", "0", "1", "--population.exploit-interval", "5", "--population.exploit-fraction", "0.9"],
     "--population.exploit-fraction 0.9: the share of members"),
    (["--seeds", "0", "1", "--population.exploit-interval", "5", "--population.perturb", "hidden-dims"],
     "--population.perturb hidden-dims: PBT perturbs only settings members may differ in"),
    (["--seeds", "0", "1", "--population.exploit-interval", "5", "--population.perturb-factor", "0.8"],
     "--population.perturb-factor 0.8: settings are scaled by it or its inverse, so it must be > 1"),
])
def test_bad_pbt_inputs_are_one_clear_line(tmp_path, flags, message):
    result = call_main("train", *flags, "--device", "cpu", "--max-iterations", "1", "--logger", "none", "--log-dir",
                       tmp_path)
    assert result.returncode != 0 and message in result.stderr, result.stdout + result.stderr
    assert "Traceback" not in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_train_py_names_the_mode_and_writes_the_lineage(tmp_path):
    """The program's first lines name PBT; population.json and members.md carry it."""
    result = call_main("train", "--seeds", "0", "1", "2", "--population.exploit-interval", "2", "--num-envs", "16",
                       "--max-iterations", "4", "--device", "cpu", "--logger", "none", "--log-dir", tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "population mode: population-based training every 2 iterations" in result.stdout
    run = only_run(tmp_path)
    table = json.loads((run / POPULATION_FILE).read_text())
    assert table["exploitation"]["interval"] == 2 and "took the state of" in (run / MEMBERS_FILE).read_text()
    assert table["exploitation"]["exploits"] == result.stdout.count("pbt, iteration") > 0


def test_a_population_mode_is_refused_under_torchrun():
    from cartpole_warp.rl.modes import UntilFirstSolved, check_modes
    from cartpole_warp.settings.config import ConfigError

    with pytest.raises(ConfigError, match="in one process: run it without torchrun"):
        check_modes([UntilFirstSolved(), Exploitation(3)], 4, distributed=True)
