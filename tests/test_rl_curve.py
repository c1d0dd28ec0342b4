"""The learning curve (``rl/curve.py``): a PNG that decodes, for every task."""


import pytest
from PIL import Image

from cartpole_warp import tasks
from cartpole_warp.rl.curve import plot_learning_curve


@pytest.mark.parametrize("task", tasks.names())
def test_learning_curve_png_decodes(tmp_path, task):
    history = [{"iteration": i, "episodes": i, "mean_reward_per_step": i / 10, "time_limit_fraction": i / 9,
                "full_reward_per_step": i / 11 if i > 4 else None} for i in range(10)]
    for i in (4, 9):
        history[i]["evaluation"] = {"mean_reward_per_step": i / 9, "time_limit_fraction": i / 9,
                                    "full_reward_per_step": i / 9}
    path = plot_learning_curve(tmp_path / "curve.png", history, solved=tasks.get(task).solved)
    image = Image.open(path)
    image.load()
    assert image.size == (800, 600) and len(image.getcolors(maxcolors=100000)) > 50
