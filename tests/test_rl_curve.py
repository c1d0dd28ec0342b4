"""The learning curve (``rl/curve.py``): a PNG that decodes, for every task, with a panel per quantity its rule
judges and its play metric; the verdict on the figure (solved at which iteration, or what the last evaluation missed)
and the rule over it; short runs drawn over the iterations run, with no legend entry for a line not drawn."""

import pytest
from PIL import Image

from cartpole_warp import tasks
from cartpole_warp.rl.curve import curve_panels, learning_curve_figure, plot_learning_curve, verdict


def run_history(iterations: int, evaluations: dict[int, dict], solved_at: int | None = None) -> list[dict]:
    """A run's history as ``Progress`` keeps it: training means each iteration (no full-length episode before
    iteration 32, as in a swing-up's first iterations), ``evaluations`` by iteration, ``solved`` from ``solved_at``."""
    history = []
    for i in range(iterations):
        entry = {"iteration": i, "train_time_s": 0.1 * (i + 1), "episodes": 3, "mean_reward_per_step": i / iterations,
                 "time_limit_fraction": 0.0, "full_reward_per_step": 0.5 if i >= 32 else None,
                 "solved": solved_at is not None and i >= solved_at}
        if i in evaluations:
            entry["evaluation"] = evaluations[i]
        history.append(entry)
    return history


def texts(figure) -> tuple[str, list[str]]:
    """The figure's title and every legend's entries."""
    legends = [text.get_text() for axes in figure.axes if axes.get_legend() for text in axes.get_legend().get_texts()]
    return " ".join(figure.get_suptitle().split()), legends


@pytest.mark.parametrize("task", tasks.names())
def test_learning_curve_png_decodes(tmp_path, task):
    history = [{"iteration": i, "episodes": i, "mean_reward_per_step": i / 10, "time_limit_fraction": i / 9,
                "full_reward_per_step": i / 11 if i > 4 else None} for i in range(10)]
    for i in (4, 9):
        history[i]["evaluation"] = {"mean_reward_per_step": i / 9, "time_limit_fraction": i / 9,
                                    "full_reward_per_step": i / 9}
    path = plot_learning_curve(tmp_path / "curve.png", history, tasks.get(task), f"{task}: run test")
    image = Image.open(path)
    image.load()
    assert image.size == (800, 600) and len(image.getcolors(maxcolors=100000)) > 50


def test_the_panels_are_the_rules_quantities_and_the_play_metric():
    assert curve_panels(tasks.get("cartpole-balance")) == ["mean_reward_per_step", "time_limit_fraction"]
    assert curve_panels(tasks.get("cartpole-swingup")) == ["full_reward_per_step"], "no flat time-limit panel"
    assert curve_panels(tasks.get("cartpole-swingup-sparse")) == ["full_reward_per_step"]
    assert curve_panels(tasks.get("cart-double-pole-balance")) == ["mean_reward_per_step", "time_limit_fraction"]
    for name in tasks.names():
        assert tasks.get(name).play_metric in curve_panels(tasks.get(name)), name


def test_an_unsolved_balance_says_which_condition_its_last_evaluation_missed():
    """The issue's 30-iteration balance: its last evaluation's reward per step is above the line, its time-limit
    fraction is 0; the figure says it is not solved and why, and that the rule is every line of it."""
    history = run_history(30, {24: {"mean_reward_per_step": 0.924, "time_limit_fraction": 0.0}})
    figure = learning_curve_figure(history, tasks.get("cartpole-balance"), "cartpole-balance: run test")
    title, legends = texts(figure)
    assert "NOT SOLVED: the last evaluation (iteration 25)" in title
    assert "mean reward per step 0.924 (met: >= 0.900)" in title
    assert "episodes reaching the time limit 0% (needs >= 95%)" in title
    rule = figure.axes[0].get_title().replace("\n", " ")
    assert rule == ("solved = one evaluation meets every dashed line: mean reward per step >= 0.9 and >= 95% of the "
                    "episodes reach the time limit")
    assert legends.count("training episodes") == 1, "no training line beside the time-limit fraction's evaluations"
    assert figure.axes[-1].get_xlim() == (0.5, 30.5)


def test_a_solved_run_says_at_which_iteration():
    history = run_history(50, {24: {"mean_reward_per_step": 0.92, "time_limit_fraction": 0.0},
                               49: {"mean_reward_per_step": 0.998, "time_limit_fraction": 1.0}}, solved_at=49)
    solved, words = verdict(history, tasks.get("cartpole-balance").solved)
    assert solved and words.startswith("SOLVED at iteration 50 (5.0 s of training)")
    figure = learning_curve_figure(history, tasks.get("cartpole-balance"), "run")
    assert "SOLVED at iteration 50" in texts(figure)[0] and "NOT" not in texts(figure)[0]


def test_a_short_swingup_is_drawn_over_its_iterations_with_no_entry_for_a_line_not_drawn():
    """30 iterations of the swing-up: no full-length training episode yet, one evaluation at iteration 25."""
    history = run_history(30, {24: {"full_reward_per_step": 0.13, "time_limit_fraction": 1.0}})
    figure = learning_curve_figure(history, tasks.get("cartpole-swingup"), "run")
    title, legends = texts(figure)
    assert "training episodes" not in legends and "evaluation\n(deterministic policy)" in legends
    assert "no training episode has run the whole time limit yet" in [t.get_text() for t in figure.axes[0].texts]
    assert figure.axes[-1].get_xlim() == (0.5, 30.5), "the iterations run, not the one evaluation's neighbours"
    assert "mean reward per step of full-length episodes 0.130 (needs >= 0.800)" in title
    assert verdict(run_history(3, {}), tasks.get("cartpole-swingup").solved) == (
        False, "NOT SOLVED: no evaluation in 3 iterations")


def test_the_conditions_are_the_rules_lines_with_their_values():
    """Each condition the figure names, as the rules say them in words: the balance's reward per step >= 0.9 and
    time-limit fraction >= 95%, the swing-up's reward per step of full-length episodes >= 0.8 (none: not met)."""
    balance, swingup = tasks.get("cartpole-balance").solved, tasks.get("cartpole-swingup").solved
    assert balance.conditions({"mean_reward_per_step": 0.924, "time_limit_fraction": 0.0}) == [
        ("mean_reward_per_step", 0.924, 0.9, True), ("time_limit_fraction", 0.0, 0.95, False)]
    assert balance.conditions({"mean_reward_per_step": 0.9, "time_limit_fraction": 0.95})[1][3]
    assert swingup.conditions({"mean_reward_per_step": 0.9, "full_reward_per_step": None}) == [
        ("full_reward_per_step", None, 0.8, False)]
    assert tasks.get("cart-double-pole-balance").solved.conditions({"time_limit_fraction": 0.96}) == [
        ("time_limit_fraction", 0.96, 0.95, True)]
