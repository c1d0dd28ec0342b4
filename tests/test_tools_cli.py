"""The measuring tools' command lines (``tools/``) and the recording player (``viz.web``): an unusable value is one
line and exit 2, before any measurement."""

import contextlib
import importlib
import io

import pytest

TASKS = "known tasks: cartpole-balance, "


@pytest.mark.parametrize("module, args, message", [
    ("tools.bench", ["--seconds", "-1"], "error: --seconds must be finite and > 0, got -1.0"),
    ("tools.sweep", ["--seeds", "-1"], "error: --seeds must be >= 0, got [-1]"),
    ("tools.sweep", ["--task", "nope"], f"error: unknown task 'nope'; {TASKS}"),
    ("tools.sweep", ["--num-envs", "0"], "error: --num-envs must be >= 1, got 0"),
    ("tools.timing", ["--task", "nope"], f"error: unknown task 'nope'; {TASKS}"),
    ("tools.timing", ["--learner", "sapg"], "error: tools.timing splits a PPO iteration; a --learner sapg run's"),
    ("tools.nodes", ["--steps", "0"], "error: --steps must be >= 1, got 0"),
    ("tools.nodes", ["--task", "nope"], f"error: unknown task 'nope'; {TASKS}"),
    ("tools.nodes", ["--solver", "mujoco", "--tile-gemm", "on"], "error: sim.tile_gemm='on' is SolverFeatherstone's"),
    ("tools.encoder", ["--task", "nope"], f"error: unknown task 'nope'; {TASKS}"),
    ("tools.encoder", ["--task", "cartpole-balance-rgb", "--device", "cpu"], "error: encoder timing needs a task seen"),
    ("tools.encoder", ["--task", "cartpole-balance", "--device", "cpu"], "error: encoder timing needs a task seen"),
    ("tools.gradcheck", ["--horizon", "0"], "error: --horizon must be >= 1, got 0"),
    ("tools.gradcheck", ["--task", "nope"], f"error: unknown task 'nope'; {TASKS}"),
    ("tools.gradcheck", ["--task", "cartpole-balance-rgb"], "error: a differentiable rollout runs state tasks"),
    ("viz.web", ["README.md", "99999"], "usage: python -m cartpole_warp.viz.web RECORDING.viser [PORT]"),
    ("viz.web", ["README.md", "abc"], "usage: python -m cartpole_warp.viz.web RECORDING.viser [PORT]"),
])
def test_a_bad_value_is_one_line_and_exit_2(module, args, message):
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = importlib.import_module(f"cartpole_warp.{module}").main(args)
        except SystemExit as stop:
            code = stop.code
    assert code == 2 and err.getvalue().startswith(message) and err.getvalue().count("\n") == 1, err.getvalue()
