"""USD stage -> Newton (``scene.py``): stages an env cannot use are refused with one error naming the file and the
problem (units, joint types, missing or ambiguous joint names, a joint too many)."""

import re
from pathlib import Path

import newton
import pytest
import torch
from conftest import sees_images
from pxr import Usd, UsdGeom, UsdPhysics

import cartpole_warp
from cartpole_warp.engine.scene import JointRole, pick_joint
from cartpole_warp.settings.files import data_path


def write_stage_with_renamed_joint(path):
    stage = Usd.Stage.Open(str(data_path("usd", "cartpole.usda")))
    stage.GetRootLayer().Export(str(path))
    stage = Usd.Stage.Open(str(path))
    UsdPhysics.RevoluteJoint(stage.GetPrimAtPath("/cartpole/poleJoint")).GetPrim().SetActive(False)
    stage.GetRootLayer().Save()


@pytest.mark.parametrize("where", ["missing", "folder"])
def test_a_missing_stage_or_a_folder_is_a_stage_error(tmp_path, where):
    """Code that catches StageError catches every stage problem, these two included (they were ConfigError)."""
    path = tmp_path / "missing.usda" if where == "missing" else tmp_path
    with pytest.raises(cartpole_warp.StageError, match=re.escape(
            f"USD stage {'not found' if where == 'missing' else 'is a folder'}: {path}")):
        cartpole_warp.make_env(num_envs=2, sim={"stage_path": str(path)})


def test_malformed_stage_and_missing_joint(tmp_path, device):
    garbage = tmp_path / "garbage.usda"
    garbage.write_text("#usda 1.0\nthis is not usd {")
    with pytest.raises(cartpole_warp.StageError, match="cannot load USD stage"):
        cartpole_warp.make_env(num_envs=2, device=device, sim={"stage_path": str(garbage)})
    renamed = tmp_path / "no_pole_joint.usda"
    write_stage_with_renamed_joint(renamed)
    with pytest.raises(cartpole_warp.StageError, match=re.escape(f"stage {renamed}: no joint named 'poleJoint' for the "
                                                                 "pole joint (set task.pole_joint)")):
        cartpole_warp.make_env(num_envs=2, device=device, sim={"stage_path": str(renamed)})
    with pytest.raises(cartpole_warp.StageError, match=re.escape(f"stage {data_path('usd', 'cartpole.usda')}: no "
                                                                 "joint named 'hinge' for the pole joint")):
        cartpole_warp.make_env(num_envs=2, device=device, task={"pole_joint": "hinge"})


def test_the_stages_of_one_and_two_poles_are_refused_by_the_other_task(device):
    """Each task names what it found in the other's stage: the double pole's three joints on the single-pole stage
    (no 'railCartJoint'), the single pole's two on Newton's double-pendulum stage (a third joint that moves)."""
    newton_stage = cartpole_warp.tasks.get("cart-double-pole-balance").env_class.stage
    with pytest.raises(cartpole_warp.StageError, match=re.escape(
            f"stage {data_path('usd', 'cartpole.usda')}: no joint named 'railCartJoint' for the cart joint (set "
            "task.cart_joint); its joints: /cartpole/cartJoint, /cartpole/poleJoint")):
        cartpole_warp.tasks.make("cart-double-pole-balance", num_envs=2, device=device,
                                 sim={"stage_path": str(data_path("usd", "cartpole.usda"))})
    with pytest.raises(cartpole_warp.StageError, match=re.escape(
            f"stage {newton_stage}: only the cart and pole joints may move, but it also has /cartPole/polePoleJoint "
            "(revolute)")):
        cartpole_warp.make_env(num_envs=2, device=device, sim={"stage_path": str(newton_stage)},
                               task={"cart_joint": "railCartJoint", "pole_joint": "cartPoleJoint"})


def edited_stage(path, edit):
    """Our stage, exported to ``path`` and changed by ``edit(stage)``."""
    stage = Usd.Stage.Open(str(data_path("usd", "cartpole.usda")))
    stage.GetRootLayer().Export(str(path))
    stage = Usd.Stage.Open(str(path))
    edit(stage)
    stage.GetRootLayer().Save()
    return str(path)


def revolute_cart_joint(stage):
    stage.RemovePrim("/cartpole/cartJoint")
    joint = UsdPhysics.RevoluteJoint.Define(stage, "/cartpole/cartJoint")
    joint.CreateBody0Rel().SetTargets(["/cartpole/rail"])
    joint.CreateBody1Rel().SetTargets(["/cartpole/cart"])
    joint.CreateAxisAttr("X")


def spherical_pole_joint(stage):
    stage.RemovePrim("/cartpole/poleJoint")
    joint = UsdPhysics.SphericalJoint.Define(stage, "/cartpole/poleJoint")
    joint.CreateBody0Rel().SetTargets(["/cartpole/cart"])
    joint.CreateBody1Rel().SetTargets(["/cartpole/pole"])
    joint.CreateLocalPos0Attr((0.12, 0.0, 0.0))


def swinging_rail(stage):
    stage.RemovePrim("/cartpole/railJoint")
    joint = UsdPhysics.RevoluteJoint.Define(stage, "/cartpole/railJoint")
    joint.CreateBody1Rel().SetTargets(["/cartpole/rail"])
    joint.CreateAxisAttr("Z")


@pytest.mark.parametrize("edit, message", [
    (lambda stage: UsdGeom.SetStageMetersPerUnit(stage, 0.01), "metersPerUnit=0.01"),
    (lambda stage: UsdPhysics.SetStageKilogramsPerUnit(stage, 0.001), "kilogramsPerUnit=0.001"),
    (revolute_cart_joint, "the cart joint /cartpole/cartJoint of .* is revolute; it must be prismatic"),
    (spherical_pole_joint, "the pole joint /cartpole/poleJoint of .* is ball; it must be revolute"),
    (swinging_rail, "only the cart and pole joints may move, but it also has /cartpole/railJoint \\(revolute\\)"),
])
def test_stages_the_task_cannot_use_are_named(tmp_path, device, edit, message):
    stage = edited_stage(tmp_path / "edited.usda", edit)
    with pytest.raises(cartpole_warp.StageError, match=message) as error:
        cartpole_warp.make_env(num_envs=2, device=device, sim={"stage_path": stage})
    assert stage in str(error.value), "every stage error names the file"


def test_joint_names_resolve_to_one_joint_or_name_the_candidates():
    labels = ["/a/slide", "/b/slide", "/a/hinge"]

    def role(name, cart=False):
        if cart:
            return JointRole("cart", name, newton.JointType.PRISMATIC, "task.cart_joint")
        return JointRole("pole", name, newton.JointType.REVOLUTE, "task.pole_joint")

    path = Path("robot.usda")
    assert pick_joint(labels, role("hinge"), path) == 2
    assert pick_joint(labels, role("/b/slide", cart=True), path) == 1
    with pytest.raises(cartpole_warp.StageError, match="stage robot.usda: 2 joints match 'slide' for the cart joint: "
                                                       "/a/slide, /b/slide; give task.cart_joint the full prim path"):
        pick_joint(labels, role("slide", cart=True), path)
    with pytest.raises(cartpole_warp.StageError, match=r"stage robot.usda: no joint named 'wheel' for the pole joint "
                                                       r"\(set task.pole_joint\); its joints: /a/slide"):
        pick_joint(labels, role("wheel"), path)


TILE_TOLERANCE = 1e-3
"""The most that SolverFeatherstone's tile and dense paths may differ by (m, rad, m/s, rad/s) in 60 env steps from one
start under one action sequence: the same equations, summed in another order (measured on the CPU: 0 for one pole, at
most 5e-5 for the chains)."""


@pytest.mark.parametrize("task_name", [name for name in cartpole_warp.tasks.names() if not sees_images(name)])
def test_the_tile_path_steps_as_the_dense_path(task_name, make):
    """Both paths of every state task from the same seed, under the same actions: the same states within
    ``TILE_TOLERANCE``, and the same ends."""
    runs = []
    for tile_gemm in ("off", "on"):
        env = make(8, seed=4, task_name=task_name, sim={"tile_gemm": tile_gemm})
        assert env.scene.solver.use_tile_gemm == (tile_gemm == "on")
        t = torch.arange(env.num_envs, device=env.device, dtype=torch.float32)
        states, ends = [], []
        for k in range(60):
            actions = torch.sin(0.3 * k + t).reshape(-1, 1).expand(-1, env.num_actions).contiguous()
            _, _, terminated, truncated, _ = env.step(actions)
            states.append(torch.cat(env.joint_state(), dim=1))
            ends.append(terminated | truncated)
        runs.append((torch.stack(states), torch.stack(ends)))
    (dense, dense_ends), (tiles, tile_ends) = runs
    assert torch.equal(dense_ends, tile_ends)
    difference = (dense - tiles).abs().max().item()
    assert difference <= TILE_TOLERANCE, difference


def test_the_tile_path_is_chosen_by_device_and_solver():
    """'auto' takes SolverFeatherstone's tile path on CUDA and its dense path on the CPU; MuJoCo has no such path, and
    'on' for it is refused; the CPU's tile path steps one shard (Warp's CPU tile arena is shared by threads)."""
    config = cartpole_warp.tasks.env_config
    auto = config("cartpole-swingup").sim
    assert auto.tile_gemm == "auto" and auto.tiles("cuda:0") and auto.tiles("cuda:1") and not auto.tiles("cpu")
    on, off = (config("cartpole-swingup", sim={"tile_gemm": choice}).sim for choice in ("on", "off"))
    assert on.tiles("cpu") and on.tiles("cuda:0") and not off.tiles("cpu") and not off.tiles("cuda:0")
    assert not config("cartpole-swingup", sim={"solver": "mujoco"}).sim.tiles("cuda:0")
    with pytest.raises(cartpole_warp.ConfigError, match="sim.tile_gemm='on' is SolverFeatherstone's tile path"):
        config("cartpole-swingup", sim={"solver": "mujoco", "tile_gemm": "on"})
    sharded = cartpole_warp.tasks.make("cartpole-swingup", num_envs=2048, device="cpu", sim={"cpu_threads": 2})
    tiled = cartpole_warp.tasks.make("cartpole-swingup", num_envs=2048, device="cpu",
                                     sim={"cpu_threads": 2, "tile_gemm": "on"})
    try:
        assert len(sharded.shards) == 2 and len(tiled.shards) == 1
        assert not sharded.scene.solver.use_tile_gemm and tiled.scene.solver.use_tile_gemm
    finally:
        sharded.close()
        tiled.close()
