"""The Newton cartpole from the stage against an independent closed-form cart + pole model."""

import math

import numpy as np
import pytest
import torch
from pxr import Usd, UsdPhysics

from cartpole_warp.config import data_path

DURATION_S = 1.2
PHYSICS_DT_S = 1.0 / 4000.0


STAGE = data_path("usd", "cartpole.usda")


def stage_parameters(path=STAGE):
    """Cart mass, pole mass, hinge-to-COM length, pole inertia about its COM (hinge axis), gravity; from the stage."""
    stage = Usd.Stage.Open(str(path))
    cart = UsdPhysics.MassAPI(stage.GetPrimAtPath("/cartpole/cart"))
    pole = UsdPhysics.MassAPI(stage.GetPrimAtPath("/cartpole/pole"))
    joint = UsdPhysics.RevoluteJoint(stage.GetPrimAtPath("/cartpole/poleJoint"))
    scene = UsdPhysics.Scene(stage.GetPrimAtPath("/physicsScene"))
    assert joint.GetAxisAttr().Get() == "X"
    hinge_in_pole = np.array(joint.GetLocalPos1Attr().Get())
    com = np.array(pole.GetCenterOfMassAttr().Get())
    return {
        "cart_mass": cart.GetMassAttr().Get(),
        "pole_mass": pole.GetMassAttr().Get(),
        "com_length": float(com[2] - hinge_in_pole[2]),
        "pole_inertia": pole.GetDiagonalInertiaAttr().Get()[0],
        "gravity": scene.GetGravityMagnitudeAttr().Get(),
    }


def closed_form_rollout(state0, forces, dt, p, substeps=10):
    """RK4 of the rigid cart + rigid pole (Lagrange equations); force held constant over each dt.

    The pole angle theta turns about +X, so the pole's COM sits at (y, z) = (x - com sin theta, com cos theta).
    """
    M, m, com, inertia, g = p["cart_mass"], p["pole_mass"], p["com_length"], p["pole_inertia"], p["gravity"]

    def deriv(s, force):
        x, xd, th, thd = s
        a11, a12 = M + m, -m * com * math.cos(th)
        a21, a22 = -m * com * math.cos(th), m * com * com + inertia
        b1 = force - m * com * math.sin(th) * thd * thd
        b2 = m * g * com * math.sin(th)
        det = a11 * a22 - a12 * a21
        return np.array([xd, (b1 * a22 - a12 * b2) / det, thd, (a11 * b2 - a21 * b1) / det])

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


@pytest.mark.parametrize("solver", ["featherstone", "mujoco"])
def test_trajectory_matches_closed_form(solver, make):
    """1.2 s under a fixed force sequence (with pulses beyond the action clip) from three starting states.

    Both solvers integrate semi-implicitly (first order): at 1/4000 s the error is about 0.5% of each
    quantity's range, and it shrinks in proportion to the step (about 2% at 1/1000 s).
    """
    p = stage_parameters()
    steps = round(DURATION_S / PHYSICS_DT_S)
    env = make(3, sim={"solver": solver, "physics_dt": PHYSICS_DT_S, "decimation": 1, "mass_matrix_interval": 1},
               task={"episode_length_s": None, "reset_dist_m": 100.0, "max_pole_angle_rad": 100.0})
    starts = torch.tensor([[0.0, 0.0, 0.1, 0.0], [0.5, -0.3, -0.2, 0.5], [-1.0, 0.4, 0.05, -0.8]])
    env.set_state(starts.to(env.device))
    t = np.arange(steps) * PHYSICS_DT_S
    pulse = np.where((t >= 0.3) & (t < 0.305), 2.5, 0.0) - np.where((t >= 0.6) & (t < 0.605), 3.0, 0.0)
    actions = np.stack([0.08 * np.sin(2 * math.pi * 1.5 * t) + pulse, 0.03 * np.cos(7 * t) - pulse, -0.02 + pulse],
                       axis=1)
    newton_traj = []
    for k in range(steps):
        step_actions = torch.tensor(actions[k], dtype=torch.float32, device=env.device).reshape(3, 1)
        obs, _, terminated, truncated, _ = env.step(step_actions)
        assert not (terminated.any() or truncated.any())
        newton_traj.append(obs.cpu().numpy().astype(np.float64))
    newton_traj = np.array(newton_traj)
    for i in range(3):
        forces = 400.0 * np.clip(actions[:, i], -1.0, 1.0)
        reference = closed_form_rollout(starts[i].numpy(), forces, PHYSICS_DT_S, p)
        err = np.abs(newton_traj[:, i] - reference).max(axis=0)
        scale = np.abs(reference).max(axis=0)
        assert (err <= 0.006 * scale + 2e-3).all(), f"env {i}: max error {err} vs trajectory range {scale}"
