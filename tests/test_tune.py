"""The Ray Tune search (``tools.tune``): a tiny search on a local Ray cluster writes its table, its plot and the trials'
run folders, ASHA stops the trial that lags at a rung, a trial that fails is reported and the search goes on; bad
inputs are one line each."""

import json

import pytest
from conftest import call_main, optional_module

from cartpole_warp.rl.runs import SUMMARY_FILE

SEARCH = ["--task", "cartpole-balance", "--trials", "3", "--members", "2", "--seed", "24", "--max-iterations", "8",
          "--grace-iterations", "2", "--reduction-factor", "2", "--max-concurrent", "1", "--metric", "mean_return",
          "--flags", "num-envs=64 eval.num-envs=16 eval.min-interval=1 eval.max-interval=2",
          "--space", "agent.algorithm.learning-rate=loguniform(3e-4,3e-3)",
          "env.task.max-pole-angle-rad=choice(1.5,0.45)", "agent.torch-compile-mode=choice(None,default)"]
"""Three trials one after another, evaluated every 2 iterations, ASHA's rungs at iterations 2 and 4; Optuna's draws
from seed 24: a pole allowed 1.5 rad, then one compiled with torch.compile (which a population refuses), then one
allowed 0.45 rad (whose episodes end sooner)."""


@pytest.fixture(scope="module")
def search(tmp_path_factory):
    optional_module("ray", "pip install -e '.[tune]'")
    log_dir = tmp_path_factory.mktemp("tune")
    result = call_main("tools.tune", *SEARCH, "--log-dir", log_dir, "--name", "tiny")
    return result, log_dir / "tiny"


@pytest.mark.slow
def test_a_search_writes_its_table_plot_and_trial_folders(search):
    result, folder = search
    assert result.returncode == 0, result.stdout + result.stderr
    trials = json.loads((folder / "search.json").read_text())
    assert len(trials) == 3
    assert (folder / "search.png").read_bytes()[:4] == b"\x89PNG"
    table = (folder / "search.md").read_text()
    completed = next(t for t in trials if t["status"] == "completed")
    assert completed["iterations"] == 8 and len(completed["members"]) == 2
    for member in completed["members"]:
        assert member["member"] in table
        run = folder / f"trial_{completed['trial']}" / member["member"]
        summary = json.loads((run / SUMMARY_FILE).read_text())
        assert summary["status"] == "completed" and summary["iterations"] == 8
        assert (run / "exported" / "policy.pt").is_file() and (run / "model_best.pt").is_file()
    rates = [dict(member["settings"])["learning_rate"] for member in completed["members"]]
    assert rates[0] != rates[1] and all(3e-4 <= rate <= 3e-3 for rate in rates), "each member draws its own"
    assert f"python play.py --headless --run {folder / ('trial_' + completed['trial'])}" in result.stdout


@pytest.mark.slow
def test_asha_stops_the_trial_below_the_median_at_a_rung_and_its_members_folders_are_written(search):
    """ASHA with reduction factor 2: a trial reaching a rung (2, 4) goes on only if its metric there is not below the
    median of the trials' metrics recorded at that rung; the trial stopped is one that was below it."""
    _, folder = search
    trials = json.loads((folder / "search.json").read_text())
    stopped = next(t for t in trials if t["status"] == "stopped early")
    completed = next(t for t in trials if t["status"] == "completed")
    assert stopped["iterations"] < 8
    rung = max(r for r in (2, 4) if r <= stopped["iterations"])
    at_rung = {t["trial"]: dict(t["history"])[rung] for t in (stopped, completed)}
    assert at_rung[stopped["trial"]] < (at_rung[stopped["trial"]] + at_rung[completed["trial"]]) / 2
    assert float(stopped["settings"]["env.task.max-pole-angle-rad"]) == 0.45
    for member in stopped["members"]:
        assert member["status"] == "stopped by the scheduler"
        summary = json.loads((folder / f"trial_{stopped['trial']}" / member["member"] / SUMMARY_FILE).read_text())
        assert summary["status"] == "stopped by the scheduler" and summary["iterations"] == rung + 1


@pytest.mark.slow
def test_a_trial_that_fails_is_reported_and_the_search_goes_on(search):
    result, folder = search
    trials = json.loads((folder / "search.json").read_text())
    failed = [t for t in trials if t["status"].startswith("failed")]
    assert len(failed) == 1 and failed[0]["settings"]["agent.torch-compile-mode"] == "default"
    assert "cannot train with agent.torch_compile_mode" in failed[0]["status"]
    lines = result.stdout.splitlines()
    said = lines.index(f"trial {failed[0]['trial']} failed (the search goes on)")
    later = {line.split()[1] for line in lines[said + 1:] if line.startswith("trial ")}
    assert later and failed[0]["trial"] not in later, "a trial ran after the failure"
    assert all(t["status"] in ("completed", "stopped early") for t in trials if t is not failed[0])


@pytest.mark.parametrize(("flags", "message"), [
    (["--space", "agent.algorithm.learnin-rate=uniform(1e-4,1e-3)"],
     "--space agent.algorithm.learnin-rate=0.0001: unknown flag"),
    (["--space", "agent.algorithm.entropy-coef=uniform(0.01,0.01)"], "an empty range (low 0.01 >= high 0.01)"),
    (["--space", "agent.actor.hidden-dims=choice()"], "an empty range (no values)"),
    (["--space", "agent.algorithm.gamma=loguniform(0,0.99)"], "loguniform needs low > 0"),
    (["--space", "agent.algorithm.gamma=choice(0.99,high)"], "the values of choice must be numbers"),
    (["--space", "seed=randint(0,9)"], "seed is set by the search for every trial"),
    (["--space", "num-envs=between(1,2)"], "write name=draw"),
    (["--space", "learning-rate=uniform(1e-4,1e-3)", "agent.algorithm.learning-rate=uniform(1e-4,1e-3)"],
     "names learning_rate twice"),
    (["--space", "env.task.max-pole-angle-rad=choice(1.5,0.05)"], "must be below task.max_pole_angle_rad=0.05"),
    (["--space", "num-envs=choice(64,128)", "--flags", "eval.min-interval=9 eval.max-interval=2"],
     "--flags 'eval.min-interval=9 eval.max-interval=2': --eval.min-interval (9) must be at most"),
    (["--space", "num-envs=choice(64,128)", "--metric", "mean_reward"], "--metric mean_reward: an evaluation's fields"),
    ([], "--space: name at least one setting to search"),
    (["--task", "nope", "--space", "num-envs=choice(64,128)"], "unknown task 'nope'; known tasks: cartpole-balance"),
    (["--trials", "0", "--space", "num-envs=choice(64,128)"], "--trials and --members must be >= 1"),
    (["--reduction-factor", "1", "--space", "num-envs=choice(64,128)"], "--reduction-factor must be > 1, got 1.0"),
])
def test_bad_search_input_is_one_line(flags, message):
    optional_module("ray", "pip install -e '.[tune]'")
    result = call_main("tools.tune", *flags)
    assert result.returncode == 2 and message in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr
