"""The Newton cart-pole of each task's stage, stepped through the env, against an independent closed-form cart + pole
model: the balance task's stage (and Newton's copy of Isaac Lab's) and the swing-up's (dm_control's model)."""

import functools
import math
from pathlib import Path

import newton.examples
import numpy as np
import pytest
import torch
from pxr import Usd, UsdGeom, UsdPhysics

from cartpole_warp.settings.files import data_path

DURATION_S = 1.2
PHYSICS_DT_S = 1.0 / 4000.0
REFERENCE_SUBSTEPS = 2
"""RK4 steps per env physics step of the closed-form references: at the tests' 1/4000 s, RK4's error (fourth order)
is many orders below the solvers' (first order) and the tolerances."""


SOLVERS = {"featherstone": {"solver": "featherstone", "tile_gemm": "off"},
           "featherstone-tiles": {"solver": "featherstone", "tile_gemm": "on"}, "mujoco": {"solver": "mujoco"}}
"""The physics paths under test: SolverFeatherstone's dense and tile paths (``sim.tile_gemm``), SolverMuJoCo."""

STAGE = data_path("usd", "cartpole.usda")
NEWTON_STAGE = Path(newton.examples.get_asset("cartpole_single_pendulum.usda"))
"""Newton's copy of Isaac Lab's cartpole: joints slider_to_cart and cart_to_pole, no authored pole inertia."""
DMC_STAGE = data_path("usd", "cartpole_dmc.usda")
"""The swing-up's stage, dm_control's cartpole: a 1 kg cart on a +-1.8 m slider, a 0.1 kg capsule pole of 1 m."""
STAGES = {
    "ours": (STAGE, {}, ("/cartpole/cart", "/cartpole/pole", "/cartpole/poleJoint")),
    "newton": (NEWTON_STAGE, {"cart_joint": "slider_to_cart", "pole_joint": "cart_to_pole"},
               ("/cartpole/cart", "/cartpole/pole", "/cartpole/cart/cart_to_pole")),
    "dmc": (DMC_STAGE, {}, ("/cartpole/cart", "/cartpole/pole", "/cartpole/poleJoint")),
}
"""Stage, the task settings that name its joints, and its cart body, pole body and pole joint prims."""


def pole_inertia_about_com(pole: Usd.Prim, mass: float, com: np.ndarray) -> float:
    """The pole's inertia about the hinge axis (X) through its centre of mass: the authored diagonal inertia, or as
    UsdPhysics derives it where none is authored, from the collision boxes (uniform density, mass shared by volume)."""
    authored = UsdPhysics.MassAPI(pole).GetDiagonalInertiaAttr().Get()
    if authored is not None and any(authored):
        return float(authored[0])
    boxes = []
    for prim in Usd.PrimRange(pole, Usd.TraverseInstanceProxies()):
        if prim.IsA(UsdGeom.Cube) and prim.HasAPI(UsdPhysics.CollisionAPI):
            local = UsdGeom.Xformable(prim).GetLocalTransformation()
            size = prim.GetAttribute("size").Get() * np.array(prim.GetAttribute("xformOp:scale").Get())
            boxes.append((size, np.array(local.ExtractTranslation())))
    volumes = np.array([np.prod(size) for size, _ in boxes])
    inertia = 0.0
    for (size, center), share in zip(boxes, volumes / volumes.sum(), strict=True):
        m = mass * share
        inertia += m * (size[1] ** 2 + size[2] ** 2) / 12 + m * ((center[1] - com[1]) ** 2 + (center[2] - com[2]) ** 2)
    return inertia


def stage_parameters(name="ours"):
    """Cart mass, pole mass, hinge-to-COM length, pole inertia about its COM (hinge axis), gravity; from the stage
    (gravity: its physics scene, or UsdPhysics' default 9.81 m/s^2 where it has none)."""
    path, _, (cart_path, pole_path, joint_path) = STAGES[name]
    stage = Usd.Stage.Open(str(path))
    cart, pole = UsdPhysics.MassAPI(stage.GetPrimAtPath(cart_path)), stage.GetPrimAtPath(pole_path)
    joint = UsdPhysics.RevoluteJoint(stage.GetPrimAtPath(joint_path))
    scenes = [UsdPhysics.Scene(prim) for prim in stage.Traverse() if prim.IsA(UsdPhysics.Scene)]
    assert joint.GetAxisAttr().Get() == "X"
    hinge_in_pole = np.array(joint.GetLocalPos1Attr().Get())
    com = np.array(UsdPhysics.MassAPI(pole).GetCenterOfMassAttr().Get())
    pole_mass = UsdPhysics.MassAPI(pole).GetMassAttr().Get()
    return {
        "cart_mass": cart.GetMassAttr().Get(),
        "pole_mass": pole_mass,
        "com_length": float(com[2] - hinge_in_pole[2]),
        "pole_inertia": pole_inertia_about_com(pole, pole_mass, com),
        "gravity": scenes[0].GetGravityMagnitudeAttr().Get() if scenes else 9.81,
    }


def closed_form_rollout(state0, forces, dt, p, substeps=REFERENCE_SUBSTEPS):
    """RK4 of the rigid cart + rigid pole (Lagrange equations); force held constant over each dt.

    The pole angle theta turns about +X, so the pole's COM sits at (y, z) = (x - com sin theta, com cos theta).
    Optional in ``p``: viscous damping of the cart (N s/m) and pole (N m s/rad) joints, and the cart's Coulomb
    friction (N), smoothed as -friction tanh(cart_vel / 0.01 m/s).
    """
    M, m, com, inertia, g = p["cart_mass"], p["pole_mass"], p["com_length"], p["pole_inertia"], p["gravity"]
    cart_damping, pole_damping = p.get("cart_damping", 0.0), p.get("pole_damping", 0.0)
    cart_friction = p.get("cart_friction", 0.0)

    def deriv(s, force):
        x, xd, th, thd = s
        a11, a12 = M + m, -m * com * math.cos(th)
        a21, a22 = -m * com * math.cos(th), m * com * com + inertia
        b1 = (force - m * com * math.sin(th) * thd * thd - cart_damping * xd
              - cart_friction * math.tanh(xd / 0.01))
        b2 = m * g * com * math.sin(th) - pole_damping * thd
        det = a11 * a22 - a12 * a21
        return np.array([xd, (b1 * a22 - a12 * b2) / det, thd, (a11 * b2 - a21 * b1) / det])

    return rk4(deriv, state0, forces, dt, substeps)


def rk4(deriv, state0, forces, dt, substeps):
    """(len(forces), state size): classic Runge-Kutta of ``deriv(state, force)`` in ``substeps`` per ``dt``, each
    force held constant over its ``dt``; the state after each ``dt``."""
    s = np.array(state0, dtype=np.float64)
    out = []
    h = dt / substeps
    for force in forces:
        for _ in range(substeps):
            k1 = deriv(s, force)
            k2 = deriv(s + 0.5 * h * k1, force)
            k3 = deriv(s + 0.5 * h * k2, force)
            k4 = deriv(s + h * k3, force)
            s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(s.copy())
    return np.array(out)


def test_stage_parameters_are_the_classic_cartpole():
    p = stage_parameters()
    assert p["cart_mass"] == pytest.approx(1.0)
    assert p["pole_mass"] == pytest.approx(1.0)
    assert p["com_length"] == pytest.approx(0.47, abs=1e-6)
    assert p["pole_inertia"] == pytest.approx(1.0 * (0.06**2 + 1.0**2) / 12, rel=1e-5)


def test_newton_stage_parameters_come_from_its_geometry():
    p = stage_parameters("newton")
    assert (p["cart_mass"], p["pole_mass"], p["gravity"]) == pytest.approx((1.0, 1.0, 9.81))
    assert p["com_length"] == pytest.approx(0.47, abs=1e-6)
    assert p["pole_inertia"] == pytest.approx((0.06**2 + 1.0**2) / 12, rel=1e-5), "derived: no inertia authored"


def test_dmc_stage_parameters_are_dm_controls():
    """dm_control's cartpole.xml: cart mass 1, pole capsule fromto 0 0 0 0 0 1 of radius 0.045 and mass 0.1; the
    pole's inertia is authored on the stage, equal to a uniform capsule's (cylinder plus two hemispheres)."""
    p = stage_parameters("dmc")
    assert (p["cart_mass"], p["pole_mass"], p["gravity"]) == pytest.approx((1.0, 0.1, 9.81))
    assert p["com_length"] == pytest.approx(0.5, abs=1e-6)
    r, h, m = 0.045, 1.0, 0.1
    cylinder, caps = math.pi * r * r * h, 4 / 3 * math.pi * r**3
    m_cyl, m_caps = m * cylinder / (cylinder + caps), m * caps / (cylinder + caps)
    capsule = m_cyl * (h * h / 12 + r * r / 4) + m_caps * (2 * r * r / 5 + h * h / 4 + 3 * h * r / 8)
    assert p["pole_inertia"] == pytest.approx(capsule, rel=1e-6)
    stage = Usd.Stage.Open(str(DMC_STAGE))
    assert UsdPhysics.MassAPI(stage.GetPrimAtPath("/cartpole/pole")).GetDiagonalInertiaAttr().HasAuthoredValue()


def observed_states(obs: np.ndarray, task: str) -> np.ndarray:
    """(..., 4) [cart_pos, cart_vel, pole_angle, pole_vel] from a task's observations (..., num_obs)."""
    if task == "cartpole-balance":
        return obs
    assert task == "cartpole-swingup"
    return np.stack([obs[..., 0], obs[..., 3], np.arctan2(obs[..., 2], obs[..., 1]), obs[..., 4]], axis=-1)


TRAJECTORY_CASES = {
    "ours": dict(task="cartpole-balance", effort_n=400.0,
                 task_settings={"reset_dist_m": 100.0, "max_pole_angle_rad": 100.0},
                 starts=[[0.0, 0.0, 0.1, 0.0], [0.5, -0.3, -0.2, 0.5], [-1.0, 0.4, 0.05, -0.8]],
                 amplitudes=(0.08, 0.03, -0.02), cart_limit_m=None),
    "dmc": dict(task="cartpole-swingup", effort_n=10.0, task_settings={},
                starts=[[0.0, 0.0, math.pi - 0.1, 0.0], [0.3, -0.3, 0.2, 0.8], [-0.4, 0.4, 2.0, -1.5]],
                amplitudes=(0.8, 0.5, -0.15), cart_limit_m=1.8),
}
"""Per stage: its task, the cart force (N) of action 1, the task settings that keep episodes running, three starting
states, the action amplitudes of ``actions`` (forces of a few percent of the balance's 400 N, up to most of the
swing-up's 10 N) and the slider's limits (m), which the closed form does not model: the cart must stay clear of them."""
TRAJECTORY_CASES["newton"] = TRAJECTORY_CASES["ours"]


def actions(steps, amplitudes):
    """(steps, 3) actions: a 1.5 Hz sine, a cosine and a constant, with pulses beyond the action clip at 0.3 s and
    0.6 s."""
    t = np.arange(steps) * PHYSICS_DT_S
    pulse = np.where((t >= 0.3) & (t < 0.305), 2.5, 0.0) - np.where((t >= 0.6) & (t < 0.605), 3.0, 0.0)
    a, b, c = amplitudes
    return np.stack([a * np.sin(2 * math.pi * 1.5 * t) + pulse, b * np.cos(7 * t) - pulse, c + pulse], axis=1)


@pytest.mark.parametrize("stage, solver", [("ours", "featherstone"), ("ours", "featherstone-tiles"), ("ours", "mujoco"),
                                           ("newton", "featherstone"), ("dmc", "featherstone"),
                                           ("dmc", "featherstone-tiles"), ("dmc", "mujoco")])
def test_trajectory_matches_closed_form(stage, solver, make):
    """1.2 s under a fixed force sequence (with pulses beyond the action clip) from three starting states, through
    the env of the stage's task (its observations read back as states; the swing-up's pole angle from its cosine and
    sine, compared modulo 2 pi: its pole swings through the bottom).

    Both solvers integrate semi-implicitly (first order): at 1/4000 s the error is about 0.5% of each
    quantity's range, and it shrinks in proportion to the step (about 2% at 1/1000 s).
    """
    p = stage_parameters(stage)
    path, joints, _ = STAGES[stage]
    case = TRAJECTORY_CASES[stage]
    steps = round(DURATION_S / PHYSICS_DT_S)
    env = make(3, task_name=case["task"],
               sim={**SOLVERS[solver], "physics_dt": PHYSICS_DT_S, "decimation": 1, "mass_matrix_interval": 1,
                    "stage_path": str(path)},
               task={"episode_length_s": None, **case["task_settings"], **joints})
    assert env.cfg.task.max_push_effort_n == case["effort_n"]
    starts = torch.tensor(case["starts"])
    env.set_state(starts.to(env.device))
    commands = actions(steps, case["amplitudes"])
    newton_traj = []
    for k in range(steps):
        step_actions = torch.tensor(commands[k], dtype=torch.float32, device=env.device).reshape(3, 1)
        obs, _, terminated, truncated, _ = env.step(step_actions)
        assert not (terminated.any() or truncated.any())
        newton_traj.append(obs.cpu().numpy().astype(np.float64))
    newton_traj = observed_states(np.array(newton_traj), case["task"])
    for i in range(3):
        forces = case["effort_n"] * np.clip(commands[:, i], -1.0, 1.0)
        reference = closed_form_rollout(starts[i].numpy(), forces, PHYSICS_DT_S, p)
        if case["cart_limit_m"] is not None:
            assert np.abs(reference[:, 0]).max() < case["cart_limit_m"] - 0.5, "the cart stays clear of the limits"
        diff = newton_traj[:, i] - reference
        diff[:, 2] = np.angle(np.exp(1j * diff[:, 2]))  # the observed angle lies in (-pi, pi]
        err = np.abs(diff).max(axis=0)
        scale = np.abs(reference).max(axis=0)
        assert (err <= 0.006 * scale + 2e-3).all(), f"env {i}: max error {err} vs trajectory range {scale}"


RANDOMIZED = {"mass_scale": {"cart": [0.5, 2.0], "pole": [0.5, 2.0]}, "com_offset_m": {"pole": [-0.2, 0.2]},
              "actuator_scale": [0.7, 1.3], "gravity_m_s2": [8.0, 11.0], "joint_damping": {"cart": [0.0, 2.0],
                                                                                           "pole": [0.0, 0.2]},
              "joint_friction": {"cart": [0.0, 1.0]}}


@pytest.mark.parametrize("solver", SOLVERS)
def test_randomized_envs_match_closed_form_each(solver, make):
    """Six envs, each with its own drawn cart and pole mass, pole centre of mass, force per action, gravity, joint
    damping and cart friction: 0.5 s of each matches the closed-form cart-pole with that env's own parameters, as
    ``physical_params()`` reports them (the pole's inertia about its centre of mass: the stage's, scaled with the
    mass)."""
    num_envs, steps = 6, round(0.5 / PHYSICS_DT_S)
    env = make(num_envs, seed=3, sim={**SOLVERS[solver], "physics_dt": PHYSICS_DT_S, "decimation": 1,
                                      "mass_matrix_interval": 1},
               task={"episode_length_s": None, "reset_dist_m": 100.0, "max_pole_angle_rad": 100.0},
               randomization=RANDOMIZED)
    params = {k: v.cpu().numpy().astype(np.float64) for k, v in env.physical_params().items()}
    stage = stage_parameters()
    assert params["pole_inertia_kg_m2"] == pytest.approx(stage["pole_inertia"] * params["pole_mass_kg"], rel=1e-5)
    assert np.ptp(params["pole_mass_kg"]) > 0.3 and np.ptp(params["pole_com_m"]) > 0.05, "the envs differ"
    starts = torch.tensor([[0.1 * i - 0.2, 0.2, 0.15 - 0.05 * i, 0.3] for i in range(num_envs)])
    env.set_state(starts.to(env.device))
    commands = np.stack([0.05 * np.sin(2 * math.pi * 1.5 * np.arange(steps) * PHYSICS_DT_S + i)
                         for i in range(num_envs)], axis=1)
    trajectory = []
    for k in range(steps):
        obs, *_ = env.step(torch.tensor(commands[k], dtype=torch.float32, device=env.device).reshape(-1, 1))
        trajectory.append(obs.cpu().numpy().astype(np.float64))
    trajectory = np.array(trajectory)
    for i in range(num_envs):
        p = {"cart_mass": params["cart_mass_kg"][i], "pole_mass": params["pole_mass_kg"][i],
             "com_length": params["pole_com_m"][i], "pole_inertia": params["pole_inertia_kg_m2"][i],
             "gravity": params["gravity_m_s2"][i], "cart_damping": params["cart_damping_n_s_m"][i],
             "pole_damping": params["pole_damping_n_m_s_rad"][i], "cart_friction": params["cart_friction_n"][i]}
        forces = params["force_per_action_n"][i] * commands[:, i]
        reference = closed_form_rollout(starts[i].numpy(), forces, PHYSICS_DT_S, p)
        err = np.abs(trajectory[:, i] - reference).max(axis=0)
        scale = np.abs(reference).max(axis=0)
        assert (err <= 0.006 * scale + 2e-3).all(), f"env {i}: max error {err} vs trajectory range {scale}"


def double_pole_parameters():
    """Newton's cart + double pendulum (``newton/examples/assets/cartpole.usda``), read from the stage: cart mass;
    per pole its mass, hinge-to-COM distance, inertia about its COM around the hinge axis (X), and pole 1's
    hinge-to-hinge length; gravity (UsdPhysics' magnitude: the stage authors none, so Earth's)."""
    stage = Usd.Stage.Open(str(DOUBLE_POLE_STAGE))
    hinge1 = UsdPhysics.RevoluteJoint(stage.GetPrimAtPath("/cartPole/cartPoleJoint"))
    hinge2 = UsdPhysics.RevoluteJoint(stage.GetPrimAtPath("/cartPole/polePoleJoint"))
    assert hinge1.GetAxisAttr().Get() == hinge2.GetAxisAttr().Get() == "X"
    assert UsdPhysics.PrismaticJoint(stage.GetPrimAtPath("/cartPole/railCartJoint")).GetAxisAttr().Get() == "Y"
    magnitude = UsdPhysics.Scene(stage.GetPrimAtPath("/physicsScene")).GetGravityMagnitudeAttr().Get()
    p = {"cart_mass": UsdPhysics.MassAPI(stage.GetPrimAtPath("/cartPole/cart")).GetMassAttr().Get(),
         "gravity": 9.81 if math.isinf(magnitude) else magnitude}  # UsdPhysics: -inf means Earth's gravity
    for i, (pole, hinge) in enumerate([("/cartPole/pole1", hinge1), ("/cartPole/pole2", hinge2)], start=1):
        mass_api = UsdPhysics.MassAPI(stage.GetPrimAtPath(pole))
        com = np.array(mass_api.GetCenterOfMassAttr().Get())
        p[f"mass{i}"] = mass_api.GetMassAttr().Get()
        p[f"com{i}"] = float(com[2] - hinge.GetLocalPos1Attr().Get()[2])
        p[f"inertia{i}"] = float(mass_api.GetDiagonalInertiaAttr().Get()[0])
    p["length1"] = float(hinge2.GetLocalPos0Attr().Get()[2] - hinge1.GetLocalPos1Attr().Get()[2])
    return p


def double_pole_rollout(state0, forces, dt, p, substeps=REFERENCE_SUBSTEPS):
    """RK4 of a rigid cart and two rigid links in a chain (Lagrange equations); force held constant over each dt.

    ``state0`` and the result are (x, x', theta1, theta1', theta2, theta2') with theta2 relative to link 1, as the
    joints measure them. In absolute angles phi1 = theta1, phi2 = theta1 + theta2 (about +X, 0 upright) the links'
    COMs sit at (y, z) = (x - c1 sin phi1, c1 cos phi1) and (x - l1 sin phi1 - c2 sin phi2, l1 cos phi1 + c2 cos phi2),
    and with a1 = m1 c1 + m2 l1, a2 = m2 c2, b = m2 l1 c2, J1 = I1 + m1 c1^2 + m2 l1^2, J2 = I2 + m2 c2^2:

        (m0 + m1 + m2) x'' - a1 cos phi1 phi1'' - a2 cos phi2 phi2'' = F - a1 sin phi1 phi1'^2 - a2 sin phi2 phi2'^2
        -a1 cos phi1 x'' + J1 phi1'' + b cos(phi1 - phi2) phi2'' = g a1 sin phi1 - b sin(phi1 - phi2) phi2'^2
        -a2 cos phi2 x'' + b cos(phi1 - phi2) phi1'' + J2 phi2'' = g a2 sin phi2 + b sin(phi1 - phi2) phi1'^2
    """
    m0, m1, m2, g = p["cart_mass"], p["mass1"], p["mass2"], p["gravity"]
    c1, c2, l1 = p["com1"], p["com2"], p["length1"]
    a1, a2, b = m1 * c1 + m2 * l1, m2 * c2, m2 * l1 * c2
    j1, j2 = p["inertia1"] + m1 * c1 * c1 + m2 * l1 * l1, p["inertia2"] + m2 * c2 * c2

    def deriv(s, force):
        x, xd, f1, f1d, f2, f2d = s
        mass = np.array([[m0 + m1 + m2, -a1 * math.cos(f1), -a2 * math.cos(f2)],
                         [-a1 * math.cos(f1), j1, b * math.cos(f1 - f2)],
                         [-a2 * math.cos(f2), b * math.cos(f1 - f2), j2]])
        rhs = np.array([force - a1 * math.sin(f1) * f1d**2 - a2 * math.sin(f2) * f2d**2,
                        g * a1 * math.sin(f1) - b * math.sin(f1 - f2) * f2d**2,
                        g * a2 * math.sin(f2) + b * math.sin(f1 - f2) * f1d**2])
        xdd, f1dd, f2dd = np.linalg.solve(mass, rhs)
        return np.array([xd, xdd, f1d, f1dd, f2d, f2dd])

    x, xd, t1, t1d, t2, t2d = state0
    s = rk4(deriv, [x, xd, t1, t1d, t1 + t2, t1d + t2d], forces, dt, substeps)
    return np.stack([s[:, 0], s[:, 1], s[:, 2], s[:, 3], s[:, 4] - s[:, 2], s[:, 5] - s[:, 3]], axis=1)


DOUBLE_POLE_STAGE = Path(newton.examples.get_asset("cartpole.usda"))


def test_double_pole_stage_parameters():
    """Newton's stage: a 1 kg cart, two 0.25 kg poles of 1 m with their COM at the middle and a thin rod's inertia."""
    p = double_pole_parameters()
    assert (p["cart_mass"], p["mass1"], p["mass2"], p["gravity"]) == pytest.approx((1.0, 0.25, 0.25, 9.81))
    assert (p["com1"], p["com2"], p["length1"]) == pytest.approx((0.5, 0.5, 1.0))
    assert p["inertia1"] == p["inertia2"] == pytest.approx(0.25 * 1.0**2 / 12, rel=0.01)


DOUBLE_POLE_STARTS = ((0.0, 0.0, math.pi - 0.3, 0.0, 0.4, 0.0), (0.5, -0.3, math.pi + 0.2, 0.5, -0.6, 1.0),
                      (0.0, 0.2, 0.05, 0.0, -0.05, 0.3), (-0.5, 0.0, -0.1, 0.4, 0.15, -0.2))
"""Two hanging starts and two upright ones: (x, x', theta1, theta1', theta2, theta2')."""


@functools.cache
def double_pole_references(steps: int) -> tuple[np.ndarray, np.ndarray]:
    """The actions (steps, 4) of ``test_double_pole_trajectory_matches_closed_form`` and the closed-form states
    (steps, 4, 6) they give from ``DOUBLE_POLE_STARTS`` (the same for both solvers: computed once)."""
    commands = actions(steps, (0.3, 0.2, -0.1))
    commands = np.concatenate([commands, commands[:, :1]], axis=1)
    p = double_pole_parameters()
    references = [double_pole_rollout(np.array(start), 40.0 * np.clip(commands[:, i], -1, 1), PHYSICS_DT_S, p)
                  for i, start in enumerate(DOUBLE_POLE_STARTS)]
    return commands, np.stack(references, axis=1)


@pytest.mark.parametrize("solver", SOLVERS)
def test_double_pole_trajectory_matches_closed_form(solver, make):
    """One env step after another for 1.2 s (hanging starts) and 0.6 s (upright ones, where the chain is unstable and
    differences grow fastest), through the cart-double-pole-balance env, against the closed-form cart + double
    pendulum with the stage's parameters; same tolerance as the single pole's."""
    starts = torch.tensor(DOUBLE_POLE_STARTS)
    env = make(4, task_name="cart-double-pole-balance",
               sim={**SOLVERS[solver], "physics_dt": PHYSICS_DT_S, "decimation": 1, "mass_matrix_interval": 1},
               task={"episode_length_s": None, "reset_dist_m": 100.0, "min_tip_height_m": -10.0})
    assert env.cfg.task.max_push_effort_n == 40.0
    env.set_state(starts.to(env.device))
    steps = round(DURATION_S / PHYSICS_DT_S)
    commands, references = double_pole_references(steps)
    trajectory = []
    for k in range(steps):
        obs, _, terminated, truncated, _ = env.step(torch.tensor(commands[k], dtype=torch.float32,
                                                                 device=env.device).reshape(4, 1))
        assert not (terminated.any() or truncated.any())
        trajectory.append(obs.cpu().numpy().astype(np.float64)[:, [0, 3, 1, 4, 2, 5]])
    trajectory = np.array(trajectory)
    for i in range(4):
        reference = references[:, i]
        length = steps if i < 2 else steps // 2
        assert np.abs(reference[:length, 0]).max() < 3.5, "the cart stays clear of the rail's 4 m limits"
        diff = trajectory[:length, i] - reference[:length]
        diff[:, [2, 4]] = np.angle(np.exp(1j * diff[:, [2, 4]]))
        err, scale = np.abs(diff).max(axis=0), np.abs(reference[:length]).max(axis=0)
        assert (err <= 0.006 * scale + 2e-3).all(), f"env {i}: max error {err} vs trajectory range {scale}"


def chain_parameters(num_poles):
    """dm_control's cart + chain of ``num_poles`` poles (``usd/cartpole_dmc_<n>poles.usda``), read from the stage: cart
    mass; per pole (all alike, checked) its mass, hinge-to-COM distance and inertia about its COM around the hinge axis
    (X); the hinge-to-hinge spacing; gravity."""
    stage = Usd.Stage.Open(str(data_path("usd", f"cartpole_dmc_{num_poles}poles.usda")))
    names = ["pole"] + [f"pole{k}" for k in range(2, num_poles + 1)]
    masses = [UsdPhysics.MassAPI(stage.GetPrimAtPath(f"/cartpole/{name}")) for name in names]
    joints = [UsdPhysics.RevoluteJoint(stage.GetPrimAtPath(f"/cartpole/{name}Joint")) for name in names]
    assert all(joint.GetAxisAttr().Get() == "X" for joint in joints)
    facts = {(m.GetMassAttr().Get(), tuple(m.GetCenterOfMassAttr().Get()), tuple(m.GetDiagonalInertiaAttr().Get()))
             for m in masses}
    assert len(facts) == 1, "identical poles"
    (mass, com, inertia), = facts
    spacings = {tuple(joint.GetLocalPos0Attr().Get()) for joint in joints[1:]}
    assert len(spacings) == 1
    return {"cart_mass": UsdPhysics.MassAPI(stage.GetPrimAtPath("/cartpole/cart")).GetMassAttr().Get(),
            "mass": mass, "com": com[2], "inertia": inertia[0], "spacing": next(iter(spacings))[2],
            "gravity": UsdPhysics.Scene(stage.GetPrimAtPath("/physicsScene")).GetGravityMagnitudeAttr().Get()}


def chain_rollout(state0, forces, dt, p, num_poles, substeps=2):
    """RK4 of a rigid cart and a chain of ``num_poles`` identical rigid poles (Lagrange equations for any number).

    With absolute pole angles phi_k (about +X, 0 upright) pole k's COM sits at (y, z) = (x - s sum_{j<k} sin phi_j -
    c sin phi_k, s sum_{j<k} cos phi_j + c cos phi_k) (s the hinge spacing, c the COM's distance). With the arm of pole
    k on angle j, a_kj = s for j < k and c for j = k, A_j = m sum_k a_kj and B_ij = m sum_k a_ki a_kj:

        (m0 + n m) x'' - sum_j A_j cos phi_j phi_j'' = F - sum_j A_j sin phi_j phi_j'^2
        -A_i cos phi_i x'' + sum_j (B_ij cos(phi_i - phi_j) + I [i = j]) phi_j'' = g A_i sin phi_i
                                                                                - sum_j B_ij sin(phi_i - phi_j) phi_j'^2

    ``state0`` and the result are per joint role (position, velocity): the cart, then each pole's angle relative to
    the one below, as the joints measure them."""
    n, m, g = num_poles, p["mass"], p["gravity"]
    arms = np.tril(np.full((n, n), p["spacing"]), -1) + p["com"] * np.eye(n)
    big_a, big_b = m * arms.sum(axis=0), m * arms.T @ arms

    def deriv(state, force):
        phi, xd, phid = state[1:n + 1], state[n + 1], state[n + 2:]
        mass = np.empty((n + 1, n + 1))
        mass[0, 0] = p["cart_mass"] + n * m
        mass[0, 1:] = mass[1:, 0] = -big_a * np.cos(phi)
        diff = phi[:, None] - phi[None, :]
        mass[1:, 1:] = big_b * np.cos(diff) + p["inertia"] * np.eye(n)
        rhs = np.concatenate([[force - (big_a * np.sin(phi) * phid**2).sum()],
                              g * big_a * np.sin(phi) - (big_b * np.sin(diff)) @ phid**2])
        return np.concatenate([[xd], phid, np.linalg.solve(mass, rhs)])

    joints = np.asarray(state0, dtype=np.float64).reshape(n + 1, 2)
    absolute = np.concatenate([[joints[0]], np.cumsum(joints[1:], axis=0)])
    out = rk4(deriv, np.concatenate([absolute[:, 0], absolute[:, 1]]), forces, dt, substeps)
    q, qd = out[:, : n + 1], out[:, n + 1:]
    q[:, 2:], qd[:, 2:] = np.diff(q[:, 1:], axis=1), np.diff(qd[:, 1:], axis=1)
    return np.stack([q, qd], axis=2).reshape(len(forces), 2 * (n + 1))


def test_the_chain_reference_is_the_double_pendulums_closed_form():
    """Two derivations agree: the chain's equations for n poles at n = 2 and the double pole's own, on Newton's
    double-pole parameters, over 1 s of pushes from a tilted start."""
    p = double_pole_parameters()
    assert p["mass1"] == p["mass2"] and p["com1"] == p["com2"] and p["inertia1"] == p["inertia2"]
    chain = {"cart_mass": p["cart_mass"], "mass": p["mass1"], "com": p["com1"], "inertia": p["inertia1"],
             "spacing": p["length1"], "gravity": p["gravity"]}
    start = [0.1, 0.2, 0.3, -0.4, -0.5, 0.6]
    forces = 20.0 * np.sin(np.arange(100) * 0.1)
    closed = double_pole_rollout(start, forces, 0.01, p, substeps=10)
    numeric = chain_rollout(start, forces, 0.01, chain, 2, substeps=10)
    assert np.abs(closed).max() > 1.0
    np.testing.assert_allclose(numeric, closed, atol=1e-9)


@pytest.mark.parametrize("num_poles, task_name", [(2, "cart-two-pole-swingup"), (3, "cart-three-pole-swingup")])
@pytest.mark.parametrize("solver", SOLVERS)
def test_pole_chain_trajectory_matches_the_lagrangian(num_poles, task_name, solver, make):
    """dm_control's chain stages stepped through their swing-up envs, 1.2 s from hanging and tilted starts and 0.6 s
    from near-upright ones (the chain is unstable there), against ``chain_rollout``; the single pole's tolerance."""
    p = chain_parameters(num_poles)
    assert (p["cart_mass"], p["mass"], p["com"], p["spacing"]) == pytest.approx((1.0, 0.1, 0.5, 1.0))
    rng = np.random.default_rng(num_poles)
    starts = np.zeros((3, 2 * (num_poles + 1)))
    starts[0, 2] = math.pi - 0.3
    starts[1, 2::2] = rng.uniform(-1.0, 1.0, num_poles) + np.array([math.pi] + [0.0] * (num_poles - 1))
    starts[2, 2::2] = rng.uniform(-0.1, 0.1, num_poles)
    starts[1:, 1::2] = rng.uniform(-0.5, 0.5, (2, num_poles + 1))
    env = make(3, task_name=task_name,
               sim={**SOLVERS[solver], "physics_dt": PHYSICS_DT_S, "decimation": 1, "mass_matrix_interval": 1},
               task={"episode_length_s": None})
    env.set_state(torch.tensor(starts, dtype=torch.float32, device=env.device))
    steps = round(DURATION_S / PHYSICS_DT_S)
    commands = actions(steps, (0.8, 0.5, -0.15))
    trajectory = []
    for k in range(steps):
        env.step(torch.tensor(commands[k], dtype=torch.float32, device=env.device).reshape(3, 1))
        q = env.scene.state_0.joint_q.numpy().reshape(3, -1)
        qd = env.scene.state_0.joint_qd.numpy().reshape(3, -1)
        trajectory.append(np.stack([q, qd], axis=2).reshape(3, -1))
    trajectory = np.array(trajectory, dtype=np.float64)
    for i in range(3):
        reference = chain_rollout(starts[i], 10.0 * np.clip(commands[:, i], -1, 1), PHYSICS_DT_S, p, num_poles)
        length = steps if i < 2 else steps // 2
        assert np.abs(reference[:length, 0]).max() < 1.7, "the cart stays clear of the slider's 1.8 m limits"
        diff = trajectory[:length, i] - reference[:length]
        diff[:, 2::2] = np.angle(np.exp(1j * diff[:, 2::2]))
        err, scale = np.abs(diff).max(axis=0), np.abs(reference[:length]).max(axis=0)
        assert (err <= 0.006 * scale + 2e-3).all(), f"env {i}: max error {err} vs trajectory range {scale}"
