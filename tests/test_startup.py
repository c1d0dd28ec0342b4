"""Start-up: the library prints nothing and changes no global setting of Warp, warmup fills an empty kernel cache so
that the next build compiles nothing, Newton's modules compile without adjoints unless sim.gradients asks, a bad flag
is answered before Newton loads."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


def python(code: str, env: dict | None = None) -> subprocess.CompletedProcess:
    """``code`` in a fresh interpreter (the repository as its working folder), output captured."""
    return subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=600,
                          env={**os.environ, **(env or {})})


def test_library_use_prints_nothing_and_restores_warps_settings():
    """Every task through tasks.make and every gymnasium id through gym.make, built and stepped in a fresh process
    (Warp's greeting and module lines would appear unless the library silenced them)."""
    code = """
import gymnasium as gym, torch, warp as wp
import cartpole_warp
level, backward = wp.config.log_level, wp.config.enable_backward
for name in cartpole_warp.tasks.names():
    env = cartpole_warp.tasks.make(name, num_envs=4, device="cpu")
    env.step(torch.zeros(4, env.num_actions))
    env.set_physical_params(actuator_scale=torch.full((4,), 0.5))
    env.close()
for gym_id in [i for i in gym.registry if i.startswith("cartpole_warp/")]:
    env = gym.make(gym_id)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    env.close()
assert (wp.config.log_level, wp.config.enable_backward) == (level, backward), "a global Warp setting changed"
"""
    result = python(code)
    assert result.returncode == 0, result.stderr
    assert result.stdout == "" and result.stderr == "", result.stdout + result.stderr


def test_rendering_and_gymnasiums_env_checker_print_nothing():
    """A gymnasium env's first ``render()`` (gymnasium's ``check_env``, ``RecordVideo``) loads Newton's kinematics
    module: silently, as the build does, in a process that has loaded nothing else."""
    code = """
import warnings
import gymnasium as gym
import cartpole_warp
from gymnasium.utils.env_checker import check_env
warnings.simplefilter("ignore")  # check_env's warnings on unbounded observation spaces
env = gym.make("cartpole_warp/Cartpole-v0", render_mode="rgb_array")
check_env(env.unwrapped)
env.reset(seed=0)
assert env.render().ndim == 3
"""
    result = python(code)
    assert result.returncode == 0, result.stderr
    assert result.stdout == "" and result.stderr == "", result.stdout + result.stderr


def test_verbose_lets_warps_lines_through():
    result = python("import cartpole_warp; cartpole_warp.make_env(num_envs=4, device='cpu', verbose=True)")
    assert result.returncode == 0, result.stderr
    assert "Module cartpole_warp.tasks.balance" in result.stdout and "load on device 'cpu'" in result.stdout


@pytest.mark.parametrize("script, flags", [("train", []), ("play", ["--agent", "zero"])])
@pytest.mark.parametrize("bad, message", [(["--num-envz", "3"], "--num-envz"),
                                          (["--env.sim.stage-path", "missing.usda"],
                                           "error: USD stage not found: missing.usda"),
                                          (["--device", "gpu"], "error: unknown device 'gpu'")])
def test_a_bad_flag_is_answered_before_newton_and_torch_load(script, flags, bad, message):
    """The command line is parsed and checked before the heavy imports: a mistyped flag gets tyro's error (exit 2),
    a missing stage or an unknown device one line, without Newton or torch (seconds of import each) in the process."""
    code = f"""
import sys
from cartpole_warp.{script} import main
try:
    main({flags!r} + {bad!r})
except SystemExit as stop:
    print(stop.code, "newton" in sys.modules, "torch" in sys.modules)
"""
    result = python(code)
    assert result.stdout.split() == ["2", "False", "False"], result.stdout + result.stderr
    assert message in result.stderr


def test_play_keeps_torch_dynamo_out_of_its_process(tmp_path, run_main):
    """play.py loads the actor alone (no optimizer) and imports tensordict with its compile marks deferred, so
    Dynamo (seconds of import) stays out of its fresh process; training cannot keep it out (torch's optimizers import
    it when made), so the checkpoint is trained in this one."""
    trained = run_main("train", "--num-envs", 16, "--max-iterations", 1, "--logger", "none", "--log-dir", tmp_path)
    assert trained.returncode == 0, trained.stderr
    code = f"""
import sys
from cartpole_warp.play import main
main(['--headless', '--log-dir', {str(tmp_path)!r}, '--num-envs', '4', '--steps', '3'])
print("dynamo", "torch._dynamo" in sys.modules, "tensordict" in sys.modules)
"""
    result = python(code)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[-1] == "dynamo False True", result.stdout


def test_tensordicts_compile_marks_wait_for_dynamo_and_reach_it_on_request():
    """Importing tensordict through the library loads no Dynamo; ``mark_for_compile`` (before torch.compile) gives
    Dynamo every mark tensordict made, as if it had made them with Dynamo loaded."""
    code = """
import sys
from cartpole_warp.wrappers import tensordict_import
import torch, tensordict.utils
waiting = list(tensordict_import._waiting)
print("loaded", "torch._dynamo" in sys.modules, len(waiting))
tensordict_import.mark_for_compile()
from torch._dynamo import trace_rules
print("allowed", all(id(f) in trace_rules._allowed_callable_ids for m, f in waiting if m == "allow_in_graph"))
print("constant", tensordict.utils._lock_warn._dynamo_marked_constant, torch.compiler.allow_in_graph.__module__)
"""
    result = python(code)
    assert result.returncode == 0, result.stderr
    loaded, allowed, constant = result.stdout.splitlines()
    assert loaded.split()[:2] == ["loaded", "False"] and int(loaded.split()[2]) > 0
    assert allowed == "allowed True" and constant == "constant True torch.compiler"


def test_the_training_imports_after_dynamo_with_tensordicts_marks_made():
    """A script that loaded Dynamo first (a torch.compile of its own) imports the training: tensordict marks its
    functions at once (an endless recursion before the fix)."""
    code = """
import torch._dynamo
import cartpole_warp.rl.training
from cartpole_warp.wrappers import tensordict_import
import tensordict.utils
print(len(tensordict_import._waiting), tensordict.utils._lock_warn._dynamo_marked_constant)
"""
    result = python(code)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.split() == ["0", "True"], result.stdout


@pytest.mark.slow
def test_warmup_fills_an_empty_kernel_cache_so_that_training_and_the_differentiable_rollout_compile_nothing(tmp_path):
    """``warmup --gradients`` into an empty kernel cache compiles the task's kernels, the recorders' and those with
    adjoints, saying so for the differentiable rollout (tools.sysid's, --learner shac's); after it, a training run and
    the same rollout with its backward pass compile nothing and add nothing to the cache."""
    cache = tmp_path / "warp-cache"
    with_cache = {**os.environ, "WARP_CACHE_PATH": str(cache)}
    result = subprocess.run([sys.executable, "-m", "cartpole_warp.warmup", "--task", "cartpole-balance", "--gradients"],
                            cwd=REPO, capture_output=True, text=True, timeout=900, env=with_cache)
    assert result.returncode == 0, result.stderr
    assert "compiling Warp kernels for CartpoleBalanceEnv on cpu" in result.stdout
    assert "compiling Warp kernels for the differentiable rollout (with adjoints) on cpu" in result.stdout
    assert "cartpole-balance: ready on cpu in" in result.stdout
    folder = cache / os.listdir(cache)[0]
    filled = sorted(p.name for p in folder.iterdir())
    assert any("featherstone" in name for name in filled) and any("viewer" in name for name in filled)
    assert any(".grad" in name for name in filled), filled

    train = ["train.py", "--num-envs", "64", "--max-iterations", "1", "--logger", "none", "--env.verbose"]
    result = subprocess.run([sys.executable, *train, "--log-dir", tmp_path / "logs"], cwd=REPO, capture_output=True,
                            text=True, timeout=600, env=with_cache)
    assert result.returncode == 0, result.stdout + result.stderr
    loads = [line for line in result.stdout.splitlines() if " load on device " in line]
    assert loads and all(line.endswith("(cached)") for line in loads), "\n".join(loads)
    said = [line for line in result.stdout.splitlines() if "compiles" in line or line.startswith("compiling")]
    assert not said, f"a warm run says nothing of compiling: {said}"
    code = """
import torch
import cartpole_warp
from cartpole_warp.cli import quiet_libraries
from cartpole_warp.gradients.rollout import DifferentiableRollout
quiet_libraries()
env = cartpole_warp.make_env(num_envs=1, device="cpu", sim={"gradients": True})
q, qd = env.joint_state()
actions = torch.zeros(1, 1, 1, requires_grad=True)
DifferentiableRollout(env, horizon=1)(q, qd, actions=actions).rewards.sum().backward()
"""
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=900,
                            env=with_cache)
    assert result.returncode == 0, result.stderr
    assert "compiling" not in result.stdout, result.stdout
    assert sorted(p.name for p in folder.iterdir()) == filled, "training, the rollout and its backward compiled nothing"


def test_newtons_modules_compile_adjoints_only_where_asked():
    """The Warp option that decides whether adjoint code is compiled, on the modules each env build loads (set again
    by every build); Warp's global default stays (True)."""
    code = """
import warp as wp
import cartpole_warp
from cartpole_warp.engine.scene import model_modules, solver_modules
for gradients in (False, True, False):
    env = cartpole_warp.make_env(num_envs=4, device="cpu", sim={"gradients": gradients})
    print(sorted({m.options["enable_backward"] for m in model_modules() + solver_modules("featherstone")}),
          wp.config.enable_backward)
"""
    result = python(code)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["[False]", "True", "[True]", "True", "[False]", "True"]
