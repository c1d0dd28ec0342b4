"""Populations (``train.py --seeds``, ``rl.population``): member k's block of the env starts as a solo env of its seed,
members do not depend on each other's seeds or settings, a member's run folder plays and resumes as a solo run's, a
member gone non-finite ends alone, bad population inputs are one line each, Ctrl-C in the program finishes every
member's folder, play.py and --resume name a population folder's members; and every state task trains one.
(The members' update against rsl-rl's own PPO: tests/test_population_ppo.py.)"""

import dataclasses
import json
import signal
import subprocess
import sys

import pytest
import torch
from conftest import DEVICE, TRAINING_FRAMES, call_main, sees_images
from test_train_cli import REPO, only_run

from cartpole_warp import tasks
from cartpole_warp.rl.config import train_config
from cartpole_warp.rl.loop import TrainingLoop
from cartpole_warp.rl.modes import UntilFirstSolved
from cartpole_warp.rl.population import members_of
from cartpole_warp.rl.runs import (
    BEST_CHECKPOINT,
    CONFIG_FILE,
    CURVE_FILE,
    EXPORT_DIR,
    MEMBERS_FILE,
    POPULATION_FILE,
    SUMMARY_FILE,
    best_member,
    population_members,
)
from cartpole_warp.rl.training import Training
from cartpole_warp.settings.config import ConfigError
from cartpole_warp.wrappers.rsl_rl import RslRlVecEnv


def population(tmp_path, seeds, vary=(), task=tasks.DEFAULT_TASK, num_envs=16, **agent):
    """A population of ``task`` (a camera task's on ``TRAINING_FRAMES``)."""
    cfg = train_config(task)
    cfg.env.num_envs, cfg.env.device, cfg.agent.logger = num_envs, DEVICE, "none"
    if cfg.env.camera.enabled:
        cfg.env.camera = dataclasses.replace(cfg.env.camera, **TRAINING_FRAMES)
    cfg.agent = dataclasses.replace(cfg.agent, **agent)
    return Training(cfg, tmp_path, members=members_of(list(seeds), list(vary)))


def first_rollout(training):
    """The members' first iteration (no random episode starts): (observations (K, T, N, O), actions (K, T, N, A))
    as acted on, and the networks' parameters (K, P) after the update."""
    obs = training.env.get_observations()
    training.loop.learner.iteration(obs, 0)  # the update keeps the rollout's storage
    ppo = training.loop.learner.ppo
    return ppo.observations.clone(), ppo.actions.clone(), ppo.model.params.detach().clone()


def test_each_members_block_starts_and_steps_as_a_solo_env_of_its_seed(tmp_path):
    training = population(tmp_path, [3, 7, 11])
    observations, actions, _ = first_rollout(training)
    steps = observations.shape[1]
    for k, seed in enumerate([3, 7, 11]):
        solo = training.cfg.task_spec.env_class(dataclasses.replace(training.loop.records[k].config.env, num_envs=16))
        seen = [solo.get_observations()]
        for t in range(steps - 1):
            seen.append(solo.step(actions[k, t])[0])
        assert torch.equal(torch.stack(seen), observations[k]), f"member {k} (seed {seed})"


@pytest.mark.parametrize("change", ["seed", "learning_rate"])
def test_changing_one_member_leaves_another_members_rollout_and_update_unchanged(tmp_path, change):
    base = first_rollout(population(tmp_path / "a", [0, 1, 2], ["agent.algorithm.learning-rate=1e-3"]))
    seeds, rate = ([0, 1, 5], "1e-3") if change == "seed" else ([0, 1, 2], "1e-3")
    other = population(tmp_path / "b", seeds, [f"agent.algorithm.learning-rate={rate}"])
    if change == "learning_rate":
        other.loop.learner.ppo.learning_rate[2] = 3e-4
    changed = first_rollout(other)
    for k in (0, 1):
        assert all(torch.equal(a[k], b[k]) for a, b in zip(base, changed)), f"member {k}"
    assert not torch.equal(base[2][2], changed[2][2]), "the changed member's update differs"


def poison(training, member: int, at_iteration: int):
    """``member``'s networks non-finite (NaN weights) after the learner's iteration ``at_iteration``."""
    iteration = training.loop.learner.iteration

    def poisoned(obs, it):
        result = iteration(obs, it)
        if it == at_iteration:
            training.loop.learner.ppo.model.params.data[member] = float("nan")
        return result

    training.loop.learner.iteration = poisoned

def test_a_member_gone_non_finite_ends_alone_and_the_others_go_on(tmp_path, capsys):
    training = population(tmp_path, [0, 1, 2], max_iterations=3, init_at_random_ep_len=False)
    poison(training, member=1, at_iteration=0)
    result = training.run()
    statuses = {row["member"]: (row["status"], row["iterations"]) for row in result["members"]}
    assert statuses == {"seed0": ("completed", 3), "seed1": ("non-finite", 0), "seed2": ("completed", 3)}
    assert "seed1: its networks went non-finite in iteration 1; it ends here" in capsys.readouterr().out
    params = training.loop.learner.ppo.model.params.detach()
    assert torch.isfinite(params[[0, 2]]).all()


def test_a_member_gone_non_finite_keeps_its_finite_checkpoints_and_stays_stopped(tmp_path):
    """Member 1's networks go non-finite in iteration 1 (its second): model_0.pt, written after its first, keeps its
    finite weights and the non-finite state is iteration 1's checkpoint; a second ``learn`` trains the others only."""
    training = population(tmp_path, [0, 1, 2], max_iterations=2, init_at_random_ep_len=False, save_interval=1)
    poison(training, member=1, at_iteration=1)
    training.run()
    member = tmp_path / "seed1"
    first = torch.load(member / "model_0.pt", weights_only=False)["actor_state_dict"]
    assert all(torch.isfinite(value).all() for value in first.values()), "a finite checkpoint was overwritten"
    last = torch.load(member / "model_1.pt", weights_only=False)
    assert last["iter"] == 1 and not all(torch.isfinite(v).all() for v in last["actor_state_dict"].values())
    records = training.loop.records
    training.loop.learn(1)
    assert [record.progress.iterations for record in records] == [3, 1, 3]
    assert [record.stop_reason for record in records] == [None, "non-finite", None]


def test_a_loop_refuses_a_learner_of_another_number_of_members(tmp_path):
    training = population(tmp_path, [0, 1])
    cfg = training.loop.config
    with pytest.raises(ValueError, match="a learner of 2 members cannot train 3 runs"):
        TrainingLoop(training.env, cfg, None, learner=training.loop.learner, members=members_of([0, 1, 2]))

def test_a_members_run_folder_plays_and_resumes_as_a_solo_run(tmp_path):
    result = call_main("train", "--seeds", "4", "9", "--num-envs", "16", "--max-iterations", "2", "--device", "cpu",
                       "--logger", "none", "--log-dir", tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    run = only_run(tmp_path)
    table = json.loads((run / POPULATION_FILE).read_text())
    assert [row["member"] for row in table["members"]] == ["seed4", "seed9"]
    assert "| seed4 | completed |" in result.stdout and "2 running, 0 solved of 2" in result.stdout
    member = run / "seed9"
    summary = json.loads((member / "summary.json").read_text())
    assert summary["iterations"] == 2 and summary["env_steps"] == 2 * 16 * train_config().agent.num_steps_per_env
    assert (member / "exported" / "policy.onnx").exists()
    played = call_main("play", "--headless", "--run", member, "--num-envs", "4", "--video-length", "2")
    assert played.returncode == 0, played.stdout + played.stderr
    resumed = call_main("train", "--resume", member, "--max-iterations", "1", "--device", "cpu", "--logger", "none")
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    checkpoint = torch.load(member / "model_2.pt", weights_only=False)
    assert checkpoint["iter"] == 2 and checkpoint["infos"]["iterations"] == 3
    steps = {state["step"].item() for state in checkpoint["optimizer_state_dict"]["state"].values()}
    first = torch.load(member / "model_1.pt", weights_only=False)
    before = {state["step"].item() for state in first["optimizer_state_dict"]["state"].values()}
    assert len(steps) == len(before) == 1 and steps.pop() > before.pop() > 0, "Adam's steps carried over the resume"


def test_play_and_resume_on_a_population_folder_name_its_members_and_plain_play_says_a_newer_one_exists(tmp_path):
    solo = call_main("train", "--num-envs", "16", "--max-iterations", "1", "--device", "cpu", "--logger", "none",
                     "--log-dir", tmp_path, "--run-name", "a")
    assert solo.returncode == 0, solo.stderr
    result = call_main("train", "--seeds", "4", "9", "--num-envs", "16", "--max-iterations", "1", "--device", "cpu",
                       "--logger", "none", "--log-dir", tmp_path, "--run-name", "b")
    assert result.returncode == 0, result.stdout + result.stderr
    runs = sorted((tmp_path / "rsl_rl" / tasks.DEFAULT_TASK).iterdir())
    assert [run.name.endswith(suffix) for run, suffix in zip(runs, "ab")] == [True, True]
    population = runs[1]
    hint = (f": it is a population of 2 members (seed4, seed9); give one member's folder, e.g. the best-evaluated, "
            f"{population / 'seed4'}")
    for script, flags in (("play", ["--headless", "--run", population]), ("train", ["--resume", population])):
        refused = call_main(script, *flags)
        assert refused.returncode == 2 and refused.stderr.splitlines() == [
            f"error: no checkpoint (model_<iteration>.pt) in {population}{hint}"], refused.stderr
    played = call_main("play", "--headless", "--log-dir", tmp_path, "--num-envs", "2", "--steps", "2")
    assert played.returncode == 0, played.stderr
    assert played.stdout.splitlines()[0] == (
        f"note: playing {runs[0]}, the newest single run; the population {population} is newer (play its "
        f"best-evaluated member: --run {population / 'seed4'})")


def test_the_best_evaluated_member_is_a_solved_one_then_the_highest_play_metric(tmp_path):
    def member(name, best):
        (tmp_path / name).mkdir()
        (tmp_path / name / "summary.json").write_text(json.dumps({"best": best}))
        return {"member": name}

    rows = [member("seed0", None), member("seed1", {"iteration": 9, "solved": False, "time_limit_fraction": 0.9}),
            member("seed2", {"iteration": 9, "solved": True, "time_limit_fraction": 0.96}),
            member("seed3", {"iteration": 9, "solved": False, "time_limit_fraction": 0.99})]
    (tmp_path / POPULATION_FILE).write_text(json.dumps({"members": rows}))
    members = population_members(tmp_path)
    assert [m.name for m in members] == ["seed0", "seed1", "seed2", "seed3"]
    assert best_member(members).name == "seed2", "solved beats a higher metric"
    assert best_member(members[:2] + members[3:]).name == "seed3" and best_member(members[:1]).name == "seed0"
    assert population_members(tmp_path / "seed0") == []


@pytest.mark.slow
def test_ctrl_c_in_the_population_program_finishes_every_members_folder_before_the_table(tmp_path):
    """``python train.py --seeds`` in a process of its own (the program, whose exit freezes the garbage collector),
    interrupted: exit 130, each member's folder finished as a solo run's (config, checkpoint, exports, curve, then
    summary.json), then the population's table."""
    cmd = [sys.executable, str(REPO / "train.py"), "--seeds", "0", "1", "--num-envs", "16", "--max-iterations", "10000",
           "--device", "cpu", "--logger", "none", "--log-dir", str(tmp_path)]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    for line in proc.stdout:
        lines.append(line)
        if line.startswith("it ") and line.split()[1].startswith("3/"):
            proc.send_signal(signal.SIGINT)
            break
    out = "".join(lines) + proc.communicate(timeout=120)[0]
    assert proc.returncode == 130 and "Traceback" not in out, out
    run = only_run(tmp_path)
    written = {}
    for member in ("seed0", "seed1"):
        folder = run / member
        summary = json.loads((folder / SUMMARY_FILE).read_text())
        assert summary["status"] == "interrupted" and summary["iterations"] >= 3, summary
        files = [CONFIG_FILE, summary["checkpoint"], *summary["exports"], CURVE_FILE]
        assert summary["exports"] == [f"{EXPORT_DIR}/{name}" for name in ("policy.onnx", "policy.pt2", "policy.pt")]
        assert all((folder / name).stat().st_size > 0 for name in files)
        written[member] = (folder / SUMMARY_FILE).stat().st_mtime_ns
        assert max((folder / name).stat().st_mtime_ns for name in files) <= written[member], "summary.json comes last"
    table = json.loads((run / POPULATION_FILE).read_text())
    assert [row["status"] for row in table["members"]] == ["interrupted", "interrupted"]
    assert (run / MEMBERS_FILE).stat().st_mtime_ns >= max(written.values())


def test_torchrun_spreads_the_members_over_its_processes_and_each_share_trains_as_a_population_alone(repo, tmp_path):
    flags = ["--device", "cpu", "--num-envs", "16", "--max-iterations", "2", "--logger", "none"]
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
               str(repo / "train.py"), "--seeds", "4", "9", "2", *flags, "--log-dir", str(tmp_path / "spread")]
    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "rank 0: it 2/2 | 1 running" in result.stdout and "rank 1: it 2/2 | 2 running" in result.stdout
    (run,) = (tmp_path / "spread").rglob(POPULATION_FILE)
    table = json.loads(run.read_text())
    assert [row["member"] for row in table["members"]] == ["seed4", "seed9", "seed2"]
    assert table["processes"] == 2 and table["num_envs"] == 48 and result.stdout.count("| completed |") == 3
    alone = call_main("train", "--seeds", "9", "2", *flags, "--log-dir", tmp_path / "alone")
    assert alone.returncode == 0, alone.stdout + alone.stderr
    for member in ("seed9", "seed2"):  # rank 1's share, as a population of its own in one process
        spread, solo = (torch.load(next(root.rglob(f"{member}/model_1.pt")), weights_only=False)["actor_state_dict"]
                        for root in (tmp_path / "spread", tmp_path / "alone"))
        assert all(torch.allclose(spread[name], solo[name], atol=1e-6) for name in solo), member


@pytest.mark.parametrize(("flags", "message"), [
    (["--population.vary", "agent.algorithm.gamma=0.9"], "a population needs seeds: --seeds 0 1 2"),
    (["--seeds", "1", "2", "1"], "--seeds names seed 1 twice"),
    (["--seeds", "1", "--population.vary", "agent.actor.hidden-dims=64"], "agent.actor.hidden-dims: members share"),
    (["--seeds", "1", "--population.vary", "agent.algorithm.gamma=high"], "the values must be numbers"),
    (["--seeds", *map(str, range(100)), "--num-envs", "1000000"], "members of 1,000,000 envs (fewer --seeds or"),
    (["--task", "cart-double-pole-balance-rgb", "--seeds", "0", "1", "2", "3", "4", "--num-envs", "100000"],
     "a population of 5 members x 100,000 envs of cart-double-pole-balance-rgb needs about"),
    (["--seeds", "1", "--learner", "shac"], "cannot train with --learner shac"),
    (["--population.until", "first-solved"], "--population.until first-solved ends a population: give --seeds"),
])
def test_bad_population_inputs_are_one_clear_line(tmp_path, flags, message):
    result = call_main("train", *flags, "--device", "cpu", "--max-iterations", "1", "--logger", "none", "--log-dir",
                       tmp_path)
    assert result.returncode != 0 and message in result.stderr, result.stdout + result.stderr
    assert "Traceback" not in result.stderr and len(result.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("task", tasks.names())
def test_every_task_trains_a_population(tmp_path, task):
    training = population(tmp_path, [0, 1], task=task, num_envs=8, max_iterations=2)
    result = training.run()
    assert [row["iterations"] for row in result["members"]] == [2, 2]
    assert all(row["status"] == "completed" for row in result["members"])
    ppo = training.loop.learner.ppo
    assert torch.isfinite(ppo.model.params).all()
    assert (ppo.images is not None) == sees_images(task), "an actor that sees frames keeps them in the rollout"


def test_a_task_that_evaluates_inside_the_step_on_a_gpu_trains_a_population_judged_on_envs_of_its_own(tmp_path):
    cfg = train_config("cart-three-pole-swingup")
    cfg.env.num_envs, cfg.env.device, cfg.agent.logger, cfg.agent.max_iterations = 8, DEVICE, "none", 1
    cfg.eval.in_step, cfg.eval.num_envs = True, 4  # the task's GPU default
    training = Training(cfg, tmp_path, members=members_of([0, 1]))
    assert training.env.num_envs == 16 and training.env.evaluation is None, "no evaluation envs in the training's env"
    assert training.loop.evaluations.own_envs.env.num_envs == 8
    assert [row["iterations"] for row in training.run()["members"]] == [1, 1]
    assert "in_step: false" in (tmp_path / "seed1" / "config.yaml").read_text()


@pytest.mark.parametrize("task", ["cartpole-swingup", "cartpole-balance"])
def test_a_one_member_population_trains_as_rsl_rl_ppo_on_the_same_draws(tmp_path, task):
    """Three iterations of a population of one and of a solo run (``PpoLearner``: rsl-rl's storage, SyncFreePPO),
    from the same networks, with the same action noise and mini-batches (torch seeded alike before each rollout and
    update): the same observations, actions and returns, and the same networks after each update (to float tolerance:
    batched and single matrix products round apart)."""
    cfg = train_config(task)
    cfg.env.num_envs, cfg.agent.logger = 64, "none"
    cfg.agent.actor.obs_normalization = cfg.agent.critic.obs_normalization = True
    training = Training(cfg, tmp_path, members=members_of([5]))
    torch.manual_seed(5)
    member_cfg = training.loop.records[0].config
    solo = TrainingLoop(RslRlVecEnv(cfg.task_spec.env_class(member_cfg.env)), member_cfg, None)
    alg, population, ppo = solo.learner.alg, training.loop.learner, training.loop.learner.ppo
    obs, solo_obs = training.env.get_observations(), solo.env.get_observations()
    for i in range(3):
        torch.manual_seed(100 + i)
        with torch.inference_mode():
            solo_obs = solo.learner._rollout(solo_obs)
        torch.manual_seed(100 + i)
        with torch.inference_mode():
            obs = population._rollout(obs)
        torch.testing.assert_close(ppo.observations[0], alg.storage.observations["policy"], rtol=1e-4, atol=1e-4,
                                   msg=f"observations, iteration {i}")
        torch.testing.assert_close(ppo.actions[0], alg.storage.actions, rtol=1e-4, atol=1e-4)
        torch.testing.assert_close(alg.storage.returns.squeeze(-1), ppo.returns[0], rtol=1e-4, atol=1e-5)
        batch = ppo.num_envs * ppo.num_steps
        torch.manual_seed(200 + i)
        alg.update()
        torch.manual_seed(200 + i)
        ppo.update(permutation=torch.randperm(batch)[None])
        actor, critic = ppo.model.member_state_dicts(0)
        for ours, theirs in ((actor, alg.actor.state_dict()), (critic, alg.critic.state_dict())):
            for key, value in theirs.items():
                torch.testing.assert_close(ours[key], value, rtol=1e-4, atol=1e-5, msg=f"{key}, iteration {i}")


def test_each_member_trains_as_a_population_of_itself_alone_on_the_same_draws(tmp_path, monkeypatch):
    """Members do not touch each other: three iterations of a population of three, and of each member alone fed the
    same action noise (its block's rows of the population's draw) and mini-batches, give each member the same
    observations and networks (to float tolerance)."""
    cfg = train_config("cartpole-swingup")
    cfg.env.num_envs, cfg.agent.logger = 32, "none"
    together = Training(cfg, tmp_path / "together", members=members_of([3, 4, 5]))
    alone = [Training(cfg, tmp_path / f"alone{seed}", members=members_of([seed])) for seed in (3, 4, 5)]
    obs, alone_obs = together.env.get_observations(), [training.env.get_observations() for training in alone]
    ppo, draw = together.loop.learner.ppo, torch.randn_like
    for _ in range(3):
        drawn = []
        monkeypatch.setattr(torch, "randn_like", lambda t, drawn=drawn: drawn.append(draw(t)) or drawn[-1])
        with torch.inference_mode():
            obs = together.loop.learner._rollout(obs)
        permutation = torch.rand(3, ppo.num_envs * ppo.num_steps).argsort(dim=1)
        ppo.update(permutation=permutation)
        for k, training in enumerate(alone):
            rows = iter(drawn)
            monkeypatch.setattr(torch, "randn_like", lambda t, k=k, rows=rows: next(rows)[k:k + 1].clone())
            with torch.inference_mode():
                alone_obs[k] = training.loop.learner._rollout(alone_obs[k])
            training.loop.learner.ppo.update(permutation=permutation[k:k + 1])
            torch.testing.assert_close(training.loop.learner.ppo.observations[0], ppo.observations[k], rtol=1e-4,
                                       atol=1e-4)
            torch.testing.assert_close(training.loop.learner.ppo.model.params[0], ppo.model.params[k], rtol=1e-4,
                                       atol=1e-5)


def test_a_population_that_would_not_fit_in_memory_is_refused_before_it_is_built(tmp_path, monkeypatch):
    """Room for three and a half members' envs (each with its evaluation's): five members are refused in one line
    that says how many fit, before any env is built."""
    from cartpole_warp.rl import training as training_module

    cfg = train_config()
    cfg.env.num_envs, cfg.env.device, cfg.agent.logger = 16, "cpu", "none"
    per_member = (16 + cfg.eval.num_envs) * training_module.bytes_per_env_by_place(cfg, "cpu")["cpu"]
    monkeypatch.setattr(training_module, "free_memory_bytes", lambda where: int(3.5 * per_member))
    with pytest.raises(ConfigError, match=r"a population of 5 members x 16 envs of cartpole-balance needs about .* GB "
                                          r"on cpu \(with 256 evaluation envs each\); it has .* GB free: at most ~3 "
                                          r"members of 16 envs \(fewer --seeds or --num-envs\)"):
        Training(cfg, tmp_path, members=members_of([0, 1, 2, 3, 4]))
    assert not any(tmp_path.iterdir()), "nothing was written"


def test_a_population_until_its_first_solved_member_ends_there_and_plays_that_members_policy(tmp_path, monkeypatch):
    """Members judged every iteration; the judge finds member 1 (seed 8) solved after iteration 2 and the others not:
    the population ends there, seed 8 solved and the others outdone, and its folder holds seed 8's policy (config,
    model_best.pt bitwise its own, exports), which play.py --run plays."""
    from cartpole_warp.evaluation.statistics import EpisodeSummary

    cfg = train_config()
    cfg.env.num_envs, cfg.env.device, cfg.agent.logger, cfg.agent.max_iterations = 16, DEVICE, "none", 10
    cfg.eval.num_envs, cfg.eval.min_interval, cfg.eval.max_interval = 8, 1, 1
    training = Training(cfg, tmp_path, members=members_of([7, 8, 9]), modes=[UntilFirstSolved()])
    judge = training.loop.evaluations.own_envs
    verdicts = iter([{}, {}, {1: EpisodeSummary(8, 590.0, 600.0, 0.99, 1.0, 8, 0.99)}])
    failing = EpisodeSummary(8, 10.0, 20.0, 0.5, 0.0)

    def judged(members):
        solved = next(verdicts, {})
        return {k: solved.get(k, failing) for k in members}

    monkeypatch.setattr(type(judge), "__call__", lambda self, members: judged(members))
    result = training.run()
    assert result["first_solved"] == "seed8"
    assert {row["member"]: (row["status"], row["iterations"]) for row in result["members"]} == {
        "seed7": ("outdone", 3), "seed8": ("solved", 3), "seed9": ("outdone", 3)}
    ours, theirs = (torch.load(folder / BEST_CHECKPOINT, weights_only=False)
                    for folder in (tmp_path, tmp_path / "seed8"))
    assert all(torch.equal(ours["actor_state_dict"][k], v) for k, v in theirs["actor_state_dict"].items())
    assert (tmp_path / CONFIG_FILE).read_text() == (tmp_path / "seed8" / CONFIG_FILE).read_text()
    assert (tmp_path / "exported" / "policy.onnx").is_file()
    played = call_main("play", "--headless", "--run", tmp_path, "--num-envs", "4", "--video-length", "2")
    assert played.returncode == 0, played.stdout + played.stderr
    assert f"policy: {tmp_path / BEST_CHECKPOINT}" in played.stdout
