"""The learning curve (``rl/curve.py``): a PNG that decodes, for every task, with a panel per quantity its rule
judges and its play metric."""


import pytest
from PIL import Image

from cartpole_warp import tasks
from cartpole_warp.rl.curve import curve_panels, plot_learning_curve


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
