"""dm_control's cartpole as a USD stage: the committed ``usd/cartpole_dmc.usda`` is what usd/make_cartpole.py
writes, it holds the numbers of dm_control/suite/cartpole.xml, Newton reads them and simulates the closed-form
cart-pole with them; and a self-test of the numpy transcription of dm_control's swing-up reward (dmc_reference.py).
"""

import math
from pathlib import Path

import numpy as np
import pytest
import warp as wp
from dmc_reference import swingup_observations, swingup_reward, tolerance
from pxr import Gf, Usd, UsdGeom, UsdPhysics

from cartpole_warp.engine import stages

REPO = Path(__file__).resolve().parent.parent
STAGE = REPO / "usd" / "cartpole_dmc.usda"
POLE_RADIUS_M, POLE_LENGTH_M, POLE_MASS_KG, CART_MASS_KG, CART_LIMIT_M = 0.045, 1.0, 0.1, 1.0, 1.8
"""dm_control/suite/cartpole.xml: pole capsule fromto 0 0 0 0 0 1, size 0.045, mass .1; cart mass 1; slider
range -1.8 1.8."""
DMC_BODIES_XML = """<mujoco><worldbody><body name="cart"><joint name="slider" type="slide" axis="1 0 0"/>
  <geom name="cart" type="box" size="0.2 0.15 0.1" mass="1"/>
  <body name="pole_1"><joint name="hinge_1" type="hinge" axis="0 1 0"/>
    <geom name="pole_1" type="capsule" fromto="0 0 0 0 0 1" size="0.045" mass=".1"/></body>
</body></worldbody></mujoco>"""
"""The bodies of dm_control/suite/cartpole.xml (its pole default class inlined), for MuJoCo's own mass properties."""

DURATION_S = 1.2
PHYSICS_DT_S = 1.0 / 4000.0


def mujoco_mass_properties():
    """MuJoCo's body mass, centre of mass and principal inertia of dm_control's cart and pole, in the stage's axes
    (dm_control slides along X and hinges about Y; the stage slides along Y and hinges about X)."""
    import mujoco

    model = mujoco.MjModel.from_xml_string(DMC_BODIES_XML)
    swap = [1, 0, 2]
    return {name: (float(model.body_mass[i]), model.body_ipos[i][swap], model.body_inertia[i][swap])
            for i, name in ((1, "cart"), (2, "pole"))}


def test_committed_stages_match_the_script():
    writer = stages
    assert STAGE.read_text() == writer.dmc_stage_text(), "run: python usd/make_cartpole.py"
    assert writer.stage_text() != writer.dmc_stage_text()
    for n in writer.CHAINS:
        chain = STAGE.with_name(f"cartpole_dmc_{n}poles.usda")
        assert chain.read_text() == writer.dmc_stage_text(n), "run: python usd/make_cartpole.py"


@pytest.mark.parametrize("num_poles", [2, 3])
def test_a_chain_stacks_identical_poles_hinge_on_top(num_poles):
    """dm_control's ``_make_model(n)``: pole k (k >= 2) is the first pole's copy, its hinge 1 m up the pole below
    (``pos="0 0 1"``), about the same axis, and its body starts where that hinge is."""
    stage = Usd.Stage.Open(str(STAGE.with_name(f"cartpole_dmc_{num_poles}poles.usda")))
    first = UsdPhysics.MassAPI(stage.GetPrimAtPath("/cartpole/pole"))
    for k in range(2, num_poles + 1):
        body = stage.GetPrimAtPath(f"/cartpole/pole{k}")
        mass = UsdPhysics.MassAPI(body)
        assert (mass.GetMassAttr().Get(), mass.GetCenterOfMassAttr().Get(), mass.GetDiagonalInertiaAttr().Get()) == (
            first.GetMassAttr().Get(), first.GetCenterOfMassAttr().Get(), first.GetDiagonalInertiaAttr().Get())
        joint = UsdPhysics.RevoluteJoint(stage.GetPrimAtPath(f"/cartpole/pole{k}Joint"))
        below = "/cartpole/pole" if k == 2 else f"/cartpole/pole{k - 1}"
        assert [str(t) for t in joint.GetBody0Rel().GetTargets()] == [below]
        assert [str(t) for t in joint.GetBody1Rel().GetTargets()] == [f"/cartpole/pole{k}"]
        assert joint.GetAxisAttr().Get() == "X" and tuple(joint.GetLocalPos0Attr().Get()) == (0.0, 0.0, 1.0)
        origin = UsdGeom.Xformable(body).ComputeLocalToWorldTransform(Usd.TimeCode.Default()).ExtractTranslation()
        assert tuple(origin) == pytest.approx((0.0, 0.0, k - 1.0))


def test_stage_schemas_and_facts():
    stage = Usd.Stage.Open(str(STAGE))
    assert UsdGeom.GetStageUpAxis(stage) == "Z" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert UsdPhysics.GetStageKilogramsPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath() == "/cartpole"
    assert stage.GetDefaultPrim().HasAPI(UsdPhysics.ArticulationRootAPI)
    scene = UsdPhysics.Scene(stage.GetPrimAtPath("/physicsScene"))
    assert scene.GetGravityMagnitudeAttr().Get() == pytest.approx(9.81)
    assert tuple(scene.GetGravityDirectionAttr().Get()) == (0, 0, -1)

    fixed = UsdPhysics.FixedJoint(stage.GetPrimAtPath("/cartpole/railJoint"))
    assert fixed and fixed.GetBody1Rel().GetTargets()[0] == "/cartpole/rail"
    cart_joint = UsdPhysics.PrismaticJoint(stage.GetPrimAtPath("/cartpole/cartJoint"))
    assert cart_joint and cart_joint.GetAxisAttr().Get() == "Y"
    assert cart_joint.GetBody0Rel().GetTargets()[0] == "/cartpole/rail"
    assert cart_joint.GetBody1Rel().GetTargets()[0] == "/cartpole/cart"
    limits = (cart_joint.GetLowerLimitAttr().Get(), cart_joint.GetUpperLimitAttr().Get())
    assert limits == pytest.approx((-CART_LIMIT_M, CART_LIMIT_M))
    pole_joint = UsdPhysics.RevoluteJoint(stage.GetPrimAtPath("/cartpole/poleJoint"))
    assert pole_joint and pole_joint.GetAxisAttr().Get() == "X"
    assert pole_joint.GetBody0Rel().GetTargets()[0] == "/cartpole/cart"
    assert pole_joint.GetBody1Rel().GetTargets()[0] == "/cartpole/pole"
    assert tuple(pole_joint.GetLocalPos0Attr().Get()) == (0, 0, 0), "the hinge is at the cart's centre"
    assert tuple(pole_joint.GetLocalPos1Attr().Get()) == (0, 0, 0)
    assert not pole_joint.GetLowerLimitAttr().HasAuthoredValue(), "the pole turns freely"
    assert not pole_joint.GetUpperLimitAttr().HasAuthoredValue()
    assert UsdGeom.Xformable(stage.GetPrimAtPath("/cartpole/pole")).GetLocalTransformation() == \
        UsdGeom.Xformable(stage.GetPrimAtPath("/cartpole/cart")).GetLocalTransformation()

    for body in ("rail", "cart", "pole"):
        prim = stage.GetPrimAtPath(f"/cartpole/{body}")
        assert prim.HasAPI(UsdPhysics.RigidBodyAPI) and prim.HasAPI(UsdPhysics.MassAPI)
        assert UsdPhysics.MassAPI(prim).GetPrincipalAxesAttr().Get() == Gf.Quatf(1.0)
        geom = stage.GetPrimAtPath(f"/cartpole/{body}/geom")
        assert geom.HasAPI(UsdPhysics.CollisionAPI)
        assert tuple(UsdGeom.Gprim(geom).GetDisplayColorAttr().Get()[0]) != (0, 0, 0)
    assert stage.GetPrimAtPath("/cartpole/rail/geom").IsA(UsdGeom.Cube)

    cart = stage.GetPrimAtPath("/cartpole/cart/geom")
    assert cart.IsA(UsdGeom.Cube) and cart.GetAttribute("size").Get() == 1.0
    assert tuple(cart.GetAttribute("xformOp:scale").Get()) == pytest.approx((0.3, 0.4, 0.2)), "box 0.4 m along Y"
    capsule = UsdGeom.Capsule(stage.GetPrimAtPath("/cartpole/pole/geom"))
    assert capsule and capsule.GetAxisAttr().Get() == "Z"
    assert (capsule.GetRadiusAttr().Get(), capsule.GetHeightAttr().Get()) == pytest.approx((POLE_RADIUS_M, 1.0))
    assert tuple(capsule.GetPrim().GetAttribute("xformOp:translate").Get()) == pytest.approx((0, 0, 0.5))

    writer = stages
    expected = {"cart": (CART_MASS_KG, (0, 0, 0), writer.box_inertia(CART_MASS_KG, (0.3, 0.4, 0.2))),
                "pole": (POLE_MASS_KG, (0, 0, 0.5), writer.capsule_inertia(POLE_MASS_KG, POLE_RADIUS_M, 1.0))}
    for body, (mass, com, inertia) in expected.items():
        api = UsdPhysics.MassAPI(stage.GetPrimAtPath(f"/cartpole/{body}"))
        assert api.GetMassAttr().Get() == pytest.approx(mass, rel=1e-6)
        assert tuple(api.GetCenterOfMassAttr().Get()) == pytest.approx(com)
        assert tuple(api.GetDiagonalInertiaAttr().Get()) == pytest.approx(inertia, rel=1e-6)


def test_inertias_are_mujocos():
    """The capsule formula of make_cartpole.py and the stage agree with MuJoCo's own mass properties of the XML."""
    writer = stages
    mj = mujoco_mass_properties()
    pole_mass, pole_com, pole_inertia = mj["pole"]
    r, h = POLE_RADIUS_M, POLE_LENGTH_M
    assert writer.capsule_inertia(POLE_MASS_KG, r, h) == pytest.approx(tuple(pole_inertia), rel=1e-9)
    assert pole_inertia[0] == pytest.approx(0.00942459, rel=1e-5)
    assert pole_inertia[0] > POLE_MASS_KG * h * h / 12, "the caps reach past the thin rod's ends"
    stage = Usd.Stage.Open(str(STAGE))
    for body, (mass, com, inertia) in mj.items():
        api = UsdPhysics.MassAPI(stage.GetPrimAtPath(f"/cartpole/{body}"))
        assert api.GetMassAttr().Get() == pytest.approx(mass, rel=1e-6)
        assert tuple(api.GetCenterOfMassAttr().Get()) == pytest.approx(tuple(com), abs=1e-7)
        assert tuple(api.GetDiagonalInertiaAttr().Get()) == pytest.approx(tuple(inertia), rel=1e-6)


@wp.kernel
def apply_force(forces: wp.array2d(dtype=float), step: wp.array(dtype=int), dofs_per_env: int, cart_dof: int,
                joint_f: wp.array(dtype=float)):
    """The cart force of the current step, per env."""
    env = wp.tid()
    joint_f[env * dofs_per_env + cart_dof] = forces[step[0], env]


@wp.kernel
def record_state(joint_q: wp.array(dtype=float), joint_qd: wp.array(dtype=float), dofs_per_env: int, cart_dof: int,
                 pole_dof: int, step: wp.array(dtype=int), traj: wp.array3d(dtype=float)):
    """traj[step, env] = [cart_pos, cart_vel, pole_angle, pole_vel]."""
    env = wp.tid()
    k = step[0]
    traj[k, env, 0] = joint_q[env * dofs_per_env + cart_dof]
    traj[k, env, 1] = joint_qd[env * dofs_per_env + cart_dof]
    traj[k, env, 2] = joint_q[env * dofs_per_env + pole_dof]
    traj[k, env, 3] = joint_qd[env * dofs_per_env + pole_dof]


@wp.kernel
def next_step(step: wp.array(dtype=int)):
    step[0] = step[0] + 1


def force_sequence(steps, dt):
    """(steps, 3) cart forces (N) within +-10 N (dm_control's gear 10 times actions in [-1, 1]): a sine, a cosine
    with full-scale pulses, and a constant push with pulses."""
    t = np.arange(steps) * dt
    pulse = np.where((t >= 0.3) & (t < 0.32), 1.0, 0.0) - np.where((t >= 0.6) & (t < 0.62), 1.0, 0.0)
    actions = np.stack([0.8 * np.sin(2 * math.pi * 1.5 * t), 0.5 * np.cos(7 * t) - pulse, -0.15 + pulse], axis=1)
    return 10.0 * np.clip(actions, -1.0, 1.0)


@pytest.mark.parametrize("solver", ["featherstone", "mujoco"])
def test_newton_trajectory_matches_closed_form(solver):
    """Three envs from the stage in Newton (no cartpole_warp env), 1.2 s at 1/4000 s under a fixed force sequence
    from three starts (pole hanging near pi, near upright, and sideways, each with velocities), against the closed
    form of tests/test_physics.py with the stage's parameters, to test_physics's tolerance."""
    import newton
    from test_physics import closed_form_rollout

    one = newton.ModelBuilder()
    newton.solvers.SolverMuJoCo.register_custom_attributes(one)
    one.add_usd(str(STAGE), enable_self_collisions=False, collapse_fixed_joints=True)
    labels = list(one.joint_label)
    cart_dof = one.joint_qd_start[labels.index("/cartpole/cartJoint")]
    pole_dof = one.joint_qd_start[labels.index("/cartpole/poleJoint")]
    dofs = one.joint_dof_count
    assert dofs == 2 and one.joint_coord_count == 2
    builder = newton.ModelBuilder()
    builder.replicate(one, copy_count=3)
    model = builder.finalize(device="cpu")

    mj = mujoco_mass_properties()
    body = {label: i for i, label in enumerate(one.body_label)}
    for name in ("cart", "pole"):
        i = body[f"/cartpole/{name}"]
        mass, com, inertia = mj[name]
        assert model.body_mass.numpy()[i] == pytest.approx(mass, rel=1e-6)
        assert tuple(model.body_com.numpy()[i]) == pytest.approx(tuple(com), abs=1e-7)
        assert np.allclose(model.body_inertia.numpy()[i], np.diag(inertia), rtol=1e-6, atol=0)
    limits = model.joint_limit_lower.numpy()[cart_dof], model.joint_limit_upper.numpy()[cart_dof]
    assert limits == pytest.approx((-CART_LIMIT_M, CART_LIMIT_M))
    assert newton.GeoType(model.shape_type.numpy()[-1]) == newton.GeoType.CAPSULE
    assert tuple(model.shape_scale.numpy()[-1][:2]) == pytest.approx((POLE_RADIUS_M, POLE_LENGTH_M / 2))

    if solver == "featherstone":
        sim = newton.solvers.SolverFeatherstone(model, angular_damping=0.0)
    else:
        sim = newton.solvers.SolverMuJoCo(model, disable_contacts=True)
    starts = np.array([[0.0, 0.0, math.pi - 0.05, 0.0], [0.2, -0.3, 0.1, 0.8], [-0.3, 0.4, 2.0, -1.5]])
    state_0, state_1, control = model.state(), model.state(), model.control()
    q, qd = np.zeros((3, dofs)), np.zeros((3, dofs))
    q[:, cart_dof], qd[:, cart_dof], q[:, pole_dof], qd[:, pole_dof] = starts.T
    state_0.joint_q.assign(q.ravel().astype(np.float32))
    state_0.joint_qd.assign(qd.ravel().astype(np.float32))
    newton.eval_fk(model, state_0.joint_q, state_0.joint_qd, state_0)

    steps = round(DURATION_S / PHYSICS_DT_S)
    assert steps % 2 == 0, "the graph holds two steps"
    forces = force_sequence(steps, PHYSICS_DT_S).astype(np.float32)
    step = wp.zeros(1, dtype=int, device="cpu")
    forces_wp = wp.array(forces, device="cpu")
    traj = wp.zeros((steps, 3, 4), dtype=float, device="cpu")

    def two_steps():  # the force of the step, the step, its state recorded; twice, to end in state_0 again
        for current, following in ((state_0, state_1), (state_1, state_0)):
            wp.launch(apply_force, 3, inputs=[forces_wp, step, dofs, cart_dof], outputs=[control.joint_f],
                      device="cpu")  # not Warp's default device, a GPU where the host has one: the arrays are the CPU's
            sim.step(current, following, control, None, PHYSICS_DT_S)
            wp.launch(record_state, 3, inputs=[following.joint_q, following.joint_qd, dofs, cart_dof, pole_dof, step],
                      outputs=[traj], device="cpu")
            wp.launch(next_step, 1, outputs=[step], device="cpu")

    # Captured once as a Warp graph and replayed (on the CPU too): launched one by one from Python, the 4800 steps
    # took 26 s with mujoco (7 s with featherstone); replayed, well under 1 s.
    with wp.ScopedCapture(device="cpu") as capture:
        two_steps()
    for _ in range(steps // 2):
        wp.capture_launch(capture.graph)
    assert step.numpy()[0] == steps
    traj = traj.numpy().astype(np.float64)

    stage = Usd.Stage.Open(str(STAGE))
    pole = UsdPhysics.MassAPI(stage.GetPrimAtPath("/cartpole/pole"))
    p = {"cart_mass": UsdPhysics.MassAPI(stage.GetPrimAtPath("/cartpole/cart")).GetMassAttr().Get(),
         "pole_mass": pole.GetMassAttr().Get(), "com_length": pole.GetCenterOfMassAttr().Get()[2],
         "pole_inertia": pole.GetDiagonalInertiaAttr().Get()[0],
         "gravity": UsdPhysics.Scene(stage.GetPrimAtPath("/physicsScene")).GetGravityMagnitudeAttr().Get()}
    for i in range(3):
        reference = closed_form_rollout(starts[i], forces[:, i].astype(np.float64), PHYSICS_DT_S, p)
        assert np.abs(reference[:, 0]).max() < CART_LIMIT_M - 0.1, "the reference must stay clear of the limits"
        err = np.abs(traj[:, i] - reference).max(axis=0)
        scale = np.abs(reference).max(axis=0)
        assert (err <= 0.006 * scale + 2e-3).all(), f"env {i}: max error {err} vs trajectory range {scale}"


def test_reference_tolerance():
    assert tolerance(0.0, margin=2) == 1.0
    assert tolerance(2.0, margin=2) == pytest.approx(0.1), "gaussian: value_at_margin (0.1 by default) at the margin"
    assert tolerance(-2.0, margin=2) == pytest.approx(0.1)
    assert tolerance(1.0, margin=1, value_at_margin=0, sigmoid="quadratic") == 0.0
    assert tolerance(0.5, margin=1, value_at_margin=0, sigmoid="quadratic") == pytest.approx(0.75)
    assert tolerance(1.5, margin=1, value_at_margin=0, sigmoid="quadratic") == 0.0
    assert tolerance(0.3, bounds=(0.2, 0.4)) == 1.0 and tolerance(0.5, bounds=(0.2, 0.4)) == 0.0
    assert tolerance(0.9, bounds=(-0.5, 0.5), margin=0.4, value_at_margin=0.3) == pytest.approx(0.3)
    values = tolerance(np.array([0.0, 5.0, -10.0]), margin=5)
    assert values == pytest.approx([1.0, 0.1, 0.1**4]), "gaussian: value_at_margin ** (d / margin) ** 2"
    with pytest.raises(ValueError):
        tolerance(0.0, margin=1, value_at_margin=0)  # a gaussian never reaches 0


def test_reference_swingup_reward_and_observations():
    states = np.array([[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, math.pi, 0.0], [2.0, 1.0, 0.0, 5.0], [0.0, 0.0, 0.0, 0.0]])
    actions = np.array([0.0, 0.0, 0.0, 1.0])
    reward = swingup_reward(states, actions)
    assert reward.shape == (4,)
    assert reward[0] == 1.0, "upright, centred, at rest, no force"
    assert reward[1] == pytest.approx(0.0, abs=1e-15), "hanging down"
    assert reward[2] == pytest.approx(0.55 * 0.55), "centered and small_velocity each (1 + 0.1) / 2 at the margins"
    assert reward[3] == pytest.approx(0.8), "full force: small_control (4 + 0) / 5"
    obs = swingup_observations(np.array([[0.5, -1.0, math.pi / 6, 2.0]]))
    assert obs == pytest.approx(np.array([[0.5, math.cos(math.pi / 6), 0.5, -1.0, 2.0]]))
