"""A real rig's recordings (``tools.multiarm``, the multi-arm pendulum benchmark) and what ``tools.sysid`` needs for
them: a cart held still, an arm's inertia of its own, recordings at 1 kHz. References: the benchmark's own numbers (a
vendored slice, tests/data/multiarm), its authors' equations of motion integrated by scipy, and a fit's known
parameters."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch

import cartpole_warp
from cartpole_warp.evaluation.trajectories import Recording, write_trajectory
from cartpole_warp.identification import sysid
from cartpole_warp.settings.config import ConfigError
from cartpole_warp.tools import multiarm

scipy_io = pytest.importorskip("scipy.io")
DATA = Path(__file__).parent / "data" / "multiarm"
DOUBLE = DATA / "ParameterEstimation" / "DoublePendulum"


@pytest.mark.parametrize("arms", [1, 2])
def test_reader_turns_the_benchmark_into_recordings(arms):
    """Each segment is one episode at 1 kHz; pole 1's angle and velocity are arm 1's, pole 2's are arm 2's less arm
    1's (the joint's, relative to the arm below); the cart stays at 0 and no action is applied."""
    rig = multiarm.RIGS[arms]
    path = DATA / "ParameterEstimation" / rig.folder / rig.data
    raw = scipy_io.loadmat(path)
    recordings = multiarm.read_segments(path, arms)
    for name, recording in recordings.items():
        segments = [cell for cell in raw[name].reshape(-1)]
        assert np.unique(recording.episode).tolist() == list(range(len(segments)))
        for k, segment in enumerate(segments):
            rows = recording.episode == k
            np.testing.assert_allclose(recording.time_s[rows], np.arange(segment.shape[1]) * 0.001)
            np.testing.assert_array_equal(recording.q[rows, 1], segment[0])
            np.testing.assert_array_equal(recording.qd[rows, 1], segment[arms])
            if arms == 2:
                np.testing.assert_allclose(recording.q[rows, 2], segment[1] - segment[0])
                np.testing.assert_allclose(recording.qd[rows, 2], segment[3] - segment[2])
        assert (recording.q[:, 0] == 0).all() and (recording.qd[:, 0] == 0).all() and (recording.action == 0).all()


def test_held_cart_stays_and_the_arms_follow_the_authors_equations():
    """The double pendulum's stage with its cart held, given the authors' estimated parameters (each arm's inertia
    through its inertia scale), swings as the authors' equations of motion do (scipy, 1e-9 tolerance) from a
    recorded start; the cart does not move under the arms' reaction nor under the full push of the action."""
    estimates = dict(zip(multiarm.RIGS[2].estimate_names,
                         scipy_io.loadmat(DOUBLE / multiarm.RIGS[2].estimates)["EstimatedParameters"].reshape(-1)))
    env = cartpole_warp.tasks.make("cart-two-pole-swingup", num_envs=1, device="cpu",
                                   preset="multiarm_double_pendulum", task={"episode_length_s": None})
    stage = env.physical_params()
    assert abs(float(env.physics.bodies[1].com_distance) * 2 - estimates["L1"]) < 1e-5, "the drawings' L1"
    values = {"pole_mass_kg": estimates["m1"], "pole_com_m": estimates["a1"], "pole2_mass_kg": estimates["m2"],
              "pole2_com_m": estimates["a2"], "pole_damping_n_m_s_rad": estimates["k1"],
              "pole2_damping_n_m_s_rad": estimates["k2"], "gravity_m_s2": estimates["g"],
              "pole_inertia_scale": estimates["I1"] / float(stage["pole_inertia_kg_m2"]) * float(stage["pole_mass_kg"])
              / estimates["m1"],
              "pole2_inertia_scale": estimates["I2"] / float(stage["pole2_inertia_kg_m2"])
              * float(stage["pole2_mass_kg"]) / estimates["m2"]}
    env.set_physical_params(**{name: torch.tensor([float(v)]) for name, v in values.items()})
    params = env.physical_params()
    assert math.isclose(float(params["pole_inertia_kg_m2"]), estimates["I1"], rel_tol=1e-5)
    assert math.isclose(float(params["pole2_inertia_kg_m2"]), estimates["I2"], rel_tol=1e-5)
    recording = multiarm.read_segments(DOUBLE / multiarm.RIGS[2].data, 2)["Y_vad"]
    start = np.stack([recording.q[0], recording.qd[0]], axis=1).reshape(1, -1)
    start[0, 1] = 0.5  # a cart velocity: the held cart's is zeroed, and the arms swing as on a still pivot
    env.set_state(torch.tensor(start, dtype=torch.float32))
    q = [env.joint_state()[0][0].numpy().copy()]
    for t in range(50):  # 1 s of 20 ms env steps, pushing the cart with the full force half the time
        env.step(torch.full((1, 1), float(t % 2)))
        q.append(env.joint_state()[0][0].numpy().copy())
        assert float(env.joint_state()[1][0, 0]) == 0.0
    q = np.array(q)
    assert (q[:, 0] == q[0, 0]).all(), "the held cart moved"
    assert q[0, 0] == recording.q[0, 0]
    reference = multiarm.authors_prediction(
        Recording(time_s=np.arange(51) * 0.02, action=np.zeros((51, 1)), q=np.repeat(recording.q[:1], 51, axis=0),
                  qd=np.repeat(recording.qd[:1], 51, axis=0), episode=np.zeros(51)), 2, estimates)[0]
    np.testing.assert_allclose(multiarm.arm_angles(q), reference, atol=2e-3)
    assert np.abs(reference - reference[0]).max() > 0.05, "the arms swing"


def test_the_differentiable_rollout_holds_the_cart_as_the_env_does():
    """A rollout of the held-cart rig, its cart given a velocity and pushed with the full force, keeps the cart where
    it starts with no velocity, and swings the arm as the env does."""
    from cartpole_warp.gradients.rollout import DifferentiableRollout

    env = cartpole_warp.tasks.make("cartpole-swingup", num_envs=2, device="cpu", preset="multiarm_pendulum",
                                   sim={"gradients": True}, task={"episode_length_s": None})
    q0 = torch.tensor([[0.1, math.pi + 0.5], [-0.2, math.pi - 1.0]])
    qd0 = torch.tensor([[0.5, 0.0], [-0.3, 1.0]])
    actions = torch.ones((10, 2, 1))
    out = DifferentiableRollout(env, horizon=10)(q0, qd0, actions=actions)
    assert (out.q[:, :, 0] == q0[:, 0]).all() and (out.qd[1:, :, 0] == 0).all()
    env.set_state(torch.stack([q0[:, 0], qd0[:, 0], q0[:, 1], qd0[:, 1]], dim=1))
    for t in range(10):
        env.step(actions[t])
    torch.testing.assert_close(out.q[-1], env.joint_state()[0], rtol=0, atol=1e-5)


def free_swings(path: Path, hidden: dict, starts_rad: list[float], seconds: float) -> Path:
    """A recording of the single arm's rig, its cart held, swinging freely on ``hidden`` physics from each start
    (rad from hanging), at 1 kHz: the env at a 1 ms physics step, one env per episode."""
    env = cartpole_warp.tasks.make("cartpole-swingup", num_envs=len(starts_rad), device="cpu",
                                   preset="multiarm_pendulum", sim={"decimation": 1, "mass_matrix_interval": 1},
                                   task={"episode_length_s": None})
    env.set_physical_params(**{name: torch.full((len(starts_rad),), value) for name, value in hidden.items()})
    state = torch.zeros((len(starts_rad), 4))
    state[:, 2] = math.pi + torch.tensor(starts_rad)
    env.set_state(state)
    steps = round(seconds / 0.001)
    q, qd = [env.joint_state()[0].numpy().copy()], [env.joint_state()[1].numpy().copy()]
    for _ in range(steps):
        env.step(torch.zeros((len(starts_rad), 1)))
        q.append(env.joint_state()[0].numpy().copy())
        qd.append(env.joint_state()[1].numpy().copy())
    q, qd = np.array(q).transpose(1, 0, 2).reshape(-1, 2), np.array(qd).transpose(1, 0, 2).reshape(-1, 2)
    rows = steps + 1
    recording = Recording(time_s=np.tile(np.arange(rows) * 0.001, len(starts_rad)), action=np.zeros((len(q), 1)),
                          q=q, qd=qd, episode=np.repeat(np.arange(len(starts_rad), dtype=float), rows))
    return write_trajectory(path, recording, ("cart", "pole"), [True, False])


HIDDEN = {"pole_inertia_scale": 1.3, "pole_damping_n_m_s_rad": 1.5e-4, "pole_friction_n_m": 4e-4}


@pytest.mark.parametrize("batched", [False, True])
def test_fit_recovers_a_free_swing_of_known_physics(batched, tmp_path):
    """A free swing recorded by the env at 1 kHz with its cart held, on hidden physics (the arm's inertia 30% above
    the stage's shape, viscous damping and Coulomb friction), is fitted back within 1% by ``--config
    multiarm_pendulum``, with the Jacobian's columns in rollouts of their own (a CPU's default) or in the fit's own
    rollout (a GPU's); each episode simulated from its first row then follows the recording."""
    path = free_swings(tmp_path / "swing.npz", HIDDEN, [1.2, 0.5], seconds=3.0)
    result = sysid.fit(sysid.SysidArgs(trajectory=path, task="cartpole-swingup", config="multiarm_pendulum",
                                       fit=list(HIDDEN), window_steps=[50, 500], window_stride=2, guesses=1,
                                       iterations=8, batched_jacobian=batched, output=tmp_path / "fit"))
    for name, value in HIDDEN.items():
        assert result["fitted"][name] == pytest.approx(value, rel=0.01), name
    for episode in result["prediction"][str(path)]:
        assert episode["predicted_rows"] == episode["rows"] == 3001
        assert episode["rms"][1] < 1e-3
    preset = multiarm.yaml.safe_load((tmp_path / "fit" / "sysid_preset.yaml").read_text())
    assert preset["env"]["sim"]["stage_path"] == "multiarm_pendulum.usda", "the rig's stage, to train on"
    assert "held_joints" not in preset["env"]["sim"], "a policy trains with the cart free"


def test_a_moving_cart_or_an_odd_rate_is_one_clear_line(tmp_path):
    """A recording whose cart moves, fitted with the cart held, and rows every 1.5 ms, which a 1 ms physics step
    cannot divide, are refused before any fit with a line that says so."""
    path = free_swings(tmp_path / "swing.npz", HIDDEN, [0.5], seconds=0.2)
    with np.load(path) as data:
        columns = dict(data)
    moving = dict(columns, cart_pos_m=np.linspace(0.0, 0.01, len(columns["time_s"])))
    np.savez(tmp_path / "moving.npz", **moving)
    args = sysid.SysidArgs(trajectory=tmp_path / "moving.npz", task="cartpole-swingup", config="multiarm_pendulum")
    with pytest.raises(ConfigError, match="the cart joint moves in the recording .* holds it still"):
        sysid.read_problem(args)
    np.savez(tmp_path / "odd.npz", **dict(columns, time_s=columns["time_s"] * 1.5))
    args.trajectory = tmp_path / "odd.npz"
    with pytest.raises(ConfigError, match=r"rows every 0.0015 s, which the physics step sim.physics_dt=0.001 s does "
                                          "not divide"):
        sysid.read_problem(args)


def test_benchmark_command_compares_with_the_authors(tmp_path, capsys):
    """``tools.multiarm`` on the vendored slice: the recordings, the fit and a table with the authors' model's error
    on every segment, as its result file says: small over 0.6 s from the recorded start (their model of their rig;
    a reader or an equation of motion gone wrong is radians off), and what their estimates tell as their
    SinglePendulumODE.m's coefficients."""
    assert multiarm.main(["--repo", str(DATA), "--arms", "1", "--output", str(tmp_path), "--window-steps", "50",
                          "--iterations", "2", "--guesses", "1"]) == 0
    out = capsys.readouterr().out
    assert "the authors (per arm)" in out
    result = (tmp_path / "multiarm_result.yaml").read_text()
    assert (tmp_path / "y_id.npz").is_file() and (tmp_path / "y_vad.npz").is_file()
    result = multiarm.yaml.safe_load(result)
    assert len(result["segments"]["Y_id"]) == 2 and len(result["segments"]["Y_vad"]) == 1
    e = result["authors_estimates"]  # SinglePendulumODE.m: phi'' = (a1 g m1 sin(phi) - k1 phi') / (m1 a1^2 + I1)
    told = result["what_a_swing_tells"]
    assert told["authors"]["m1 a1 g / J1 (1/s^2)"] == pytest.approx(e["a1"] * e["g"] * e["m1"]
                                                                    / (e["m1"] * e["a1"] ** 2 + e["I1"]))
    assert told["authors"]["k1 / J1 (1/s)"] == pytest.approx(e["k1"] / (e["m1"] * e["a1"] ** 2 + e["I1"]))
    assert set(told["ours"]) == set(told["authors"])
    for errors in result["segments"]["Y_id"] + result["segments"]["Y_vad"]:
        assert max(errors["authors"]) < 0.02 and max(errors["ours"]) < 0.1, errors
