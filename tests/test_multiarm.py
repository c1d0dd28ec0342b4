"""A real rig's recordings (``tools.multiarm``, the multi-arm pendulum benchmark) and what ``tools.sysid`` needs for
them: a cart held still, an arm's inertia of its own, recordings at 1 kHz. References: the benchmark's own numbers (a
vendored slice, tests/data/multiarm), its authors' equations of motion integrated by scipy, and a fit's known
parameters."""

import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch

import cartpole_warp
from cartpole_warp.engine import stages
from cartpole_warp.evaluation.trajectories import Recording, write_trajectory
from cartpole_warp.identification import chain, sysid
from cartpole_warp.settings.config import ConfigError
from cartpole_warp.settings.files import data_path
from cartpole_warp.tools import multiarm

scipy_io = pytest.importorskip("scipy.io")
DATA = Path(__file__).parent / "data" / "multiarm"
DOUBLE = DATA / "ParameterEstimation" / "DoublePendulum"
AUTHORS_FILES = {1: "SinglePendulum/SinglePendulumODE.m", 2: "DoublePendulum/DoublePendulumODE_Mounted.m",
                 3: "TriplePendulum/TriplePendulumODE_Mounted.m"}
"""The authors' equations of motion, as their symbolic toolbox printed them (vendored)."""


def authors_file(arms: int):
    """The authors' MATLAB file of ``arms`` arms as a Python function of (y, parameters by name): each ``dydt(k)``
    line's expression with MATLAB's ``y(k)`` and ``^`` written as Python's, evaluated with numpy."""
    text = (DATA / "ParameterEstimation" / AUTHORS_FILES[arms]).read_text()
    names = re.search(r"function\s+dydt\s*=\s*\w+\(t,y,([^)]*)\)", text).group(1).split(",")
    lines = dict(re.findall(r"dydt\((\d),[^)]*\)\s*=\s*(.*?);", text, flags=re.S))
    code = [compile(re.sub(r"y\((\d+)(,:)?\)", lambda m: f"y[{int(m.group(1)) - 1}]", lines[k]).replace("^", "**"),
                    AUTHORS_FILES[arms], "eval") for k in sorted(lines)]
    return lambda y, p: np.array([eval(c, {"sin": np.sin, "cos": np.cos, "y": y} | {n: p[n] for n in names})
                                  for c in code])


def estimates_of(arms: int) -> dict:
    rig = multiarm.RIGS[arms]
    values = scipy_io.loadmat(DATA / "ParameterEstimation" / rig.folder / rig.estimates)["EstimatedParameters"]
    return dict(zip(rig.estimate_names, values.reshape(-1).tolist()))


@pytest.mark.parametrize("arms", [1, 2, 3])
def test_the_authors_model_is_their_files_equations(arms):
    """``chain_model``, the chain's matrix form, gives the accelerations of the authors' own printed equations
    (``*ODE*.m``) at random states with their estimates: their single, double and triple models."""
    rng = np.random.default_rng(arms)
    estimates, theirs = estimates_of(arms), authors_file(arms)
    model = multiarm.chain_model(estimates, arms)
    for _ in range(20):
        y = np.concatenate([np.pi + rng.uniform(-np.pi, np.pi, arms), rng.normal(0.0, 5.0, arms)])
        np.testing.assert_allclose(model(0.0, y), theirs(y, estimates), rtol=1e-9, atol=1e-9)


def test_the_authors_triple_model_follows_their_recordings():
    """The authors' triple model with their estimates, each vendored segment simulated from its first sample over its
    0.6 s (as their objective function does), stays within 0.01 rad RMS of every arm's recorded angle (their fit of
    their rig; a reader, a state order or an equation gone wrong is radians off)."""
    rig = multiarm.RIGS[3]
    recordings = multiarm.read_segments(DATA / "ParameterEstimation" / rig.folder / rig.data, 3)
    for recording in recordings.values():
        for errors in multiarm.rms_per_arm(multiarm.authors_prediction(recording, 3, estimates_of(3)), recording):
            assert len(errors) == 3 and max(errors) < 0.01, errors


def box_moment(mass: float, across_m: float, length_m: float) -> float:
    """A solid box's moment of inertia about its centre, around an axis across its length and its side across_m."""
    return mass * (across_m**2 + length_m**2) / 12.0


@pytest.mark.parametrize("arms", [1, 2, 3])
def test_the_rig_stage_is_the_closed_form_chain(arms):
    """The committed stage of the rig with ``arms`` arms is what ``engine.stages`` writes, and the env built on it
    holds the chain of the drawings: each arm the rig's estimated mass, its centre of mass halfway between its
    hinges (arm 3 as if its far hub held one), its inertia a 12.7 x 31.75 mm box's of its length, hinges 172.72 and
    228.6 mm apart."""
    assert (data_path("usd", stages.MULTIARM_STAGES[arms]).read_text()
            == stages.multiarm_stage_text(arms)), "run: python usd/make_cartpole.py"
    rig = multiarm.RIGS[arms]
    env = cartpole_warp.tasks.make(rig.task, num_envs=1, device="cpu", preset=rig.preset)
    params = {name: float(v[0]) for name, v in env.physical_params().items()}
    lengths, hinges = (0.220, 0.27588, 0.2413), [0.17272, 0.2286]
    centres = [0.17272 / 2, 0.2286 / 2, (0.2413 - (0.220 - 0.17272)) / 2]
    for k, role in enumerate(env.joint_roles[1:]):
        mass = stages.MULTIARM_MASSES_KG[arms][k]
        assert params[f"{role}_mass_kg"] == pytest.approx(mass, rel=1e-6)
        assert params[f"{role}_com_m"] == pytest.approx(centres[k], rel=1e-6)
        assert params[f"{role}_inertia_kg_m2"] == pytest.approx(box_moment(mass, 0.03175, lengths[k]), rel=1e-5)
    assert chain.hinge_spacings(env) == pytest.approx(hinges[:arms - 1], rel=1e-6)
    env.close()


def test_a_chain_no_rig_has_is_one_line(capsys):
    """Four arms: the stage builder and ``tools.multiarm`` refuse in one line each, naming the rigs there are."""
    with pytest.raises(ConfigError, match="the multi-arm pendulum's rigs have 1, 2, 3 arms; no stage of 4"):
        stages.multiarm_stage_text(4)
    with pytest.raises(SystemExit) as exit_:
        multiarm.main(["--repo", str(DATA), "--arms", "4"])
    assert exit_.value.code != 0
    assert capsys.readouterr().err.strip() == "error: --arms 4: the repository holds rigs of 1, 2, 3 arms"


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


def free_swings(path: Path, hidden: dict, starts_rad: list, seconds: float, arms: int = 1) -> Path:
    """A recording of the rig of ``arms`` arms (its task and preset: ``multiarm.RIGS``), its cart held, swinging
    freely on ``hidden`` physics from each start (arm 1's angle from hanging, or a tuple of it and each further
    joint's angle), at 1 kHz: the env at a 1 ms physics step, one env per episode."""
    rig, n = multiarm.RIGS[arms], len(starts_rad)
    env = cartpole_warp.tasks.make(rig.task, num_envs=n, device="cpu", preset=rig.preset,
                                   sim={"decimation": 1, "mass_matrix_interval": 1}, task={"episode_length_s": None})
    env.set_physical_params(**{name: torch.full((n,), value) for name, value in hidden.items()})
    state = torch.zeros((n, 2 * (arms + 1)))
    for e, start in enumerate(starts_rad):
        angles = start if isinstance(start, tuple) else (start,)
        for k, angle in enumerate(angles):
            state[e, 2 * (k + 1)] = angle + (math.pi if k == 0 else 0.0)
    env.set_state(state)
    steps = round(seconds / 0.001)
    q, qd = [env.joint_state()[0].numpy().copy()], [env.joint_state()[1].numpy().copy()]
    for _ in range(steps):
        env.step(torch.zeros((n, 1)))
        q.append(env.joint_state()[0].numpy().copy())
        qd.append(env.joint_state()[1].numpy().copy())
    joints = arms + 1
    q = np.array(q).transpose(1, 0, 2).reshape(-1, joints)
    qd = np.array(qd).transpose(1, 0, 2).reshape(-1, joints)
    rows = steps + 1
    recording = Recording(time_s=np.tile(np.arange(rows) * 0.001, n), action=np.zeros((len(q), 1)), q=q, qd=qd,
                          episode=np.repeat(np.arange(n, dtype=float), rows))
    return write_trajectory(path, recording, env.joint_roles, env.physics.sliders)


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
                          "--iterations", "4", "--guesses", "1", "--window-stride", "2"]) == 0
    out = capsys.readouterr().out
    assert "the authors (per arm)" in out
    result = (tmp_path / "multiarm_result.yaml").read_text()
    assert (tmp_path / "y_id.npz").is_file() and (tmp_path / "y_vad.npz").is_file()
    result = multiarm.yaml.safe_load(result)
    assert len(result["segments"]["Y_id"]) == 2 and len(result["segments"]["Y_vad"]) == 1
    e = result["authors_estimates"]  # SinglePendulumODE.m: phi'' = (a1 g m1 sin(phi) - k1 phi') / (m1 a1^2 + I1)
    told = result["what_a_swing_tells"]
    assert told["authors"]["g b1 / J1 (1/s^2)"] == pytest.approx(e["a1"] * e["g"] * e["m1"]
                                                                    / (e["m1"] * e["a1"] ** 2 + e["I1"]))
    assert told["authors"]["k1 / J1 (1/s)"] == pytest.approx(e["k1"] / (e["m1"] * e["a1"] ** 2 + e["I1"]))
    assert set(told["ours"]) == set(told["authors"])
    for errors in result["segments"]["Y_id"] + result["segments"]["Y_vad"]:
        assert max(errors["authors"]) < 0.02 and max(errors["ours"]) < 0.1, errors


def test_a_recording_of_other_joints_than_the_task_is_one_line(tmp_path):
    """The triple pendulum's recording given to the two-pole task, and the double's to the three-pole task, are
    refused before any fit, each with one line naming the recording's joints and the task's."""
    triple = multiarm.read_segments(DATA / "ParameterEstimation" / "TriplePendulum" / multiarm.RIGS[3].data, 3)
    double = multiarm.read_segments(DOUBLE / multiarm.RIGS[2].data, 2)
    three = write_trajectory(tmp_path / "three.npz", triple["Y_id"], ("cart", "pole", "pole2", "pole3"),
                             [True, False, False, False])
    two = write_trajectory(tmp_path / "two.npz", double["Y_id"], ("cart", "pole", "pole2"), [True, False, False])
    with pytest.raises(ConfigError, match=r"three.npz: a recording of more joints than the task's; its joints \(cart, "
                                          r"pole, pole2, pole3\) are not the task's \(cart, pole, pole2\)"):
        sysid.read_problem(sysid.SysidArgs(trajectory=three, task="cart-two-pole-swingup",
                                           config="multiarm_double_pendulum"))
    with pytest.raises(ConfigError, match=r"two.npz: missing columns pole3_angle_rad .*; its joints \(cart, pole, "
                                          r"pole2\) are not the task's \(cart, pole, pole2, pole3\)"):
        sysid.read_problem(sysid.SysidArgs(trajectory=two, task="cart-three-pole-swingup",
                                           config="multiarm_triple_pendulum"))


def test_the_report_names_what_the_stage_fixes():
    """On the three-arm rig: fitting arm 1's centre of mass and the three inertia scales leaves the ratio of the first
    moments about hinges 2 and 3 to the stage, b2 / b3 = (m2 a2 + L2 m3) / (m3 a3), named with its closed-form value;
    freeing arm 2's centre too leaves nothing fixed; freeing arm 3's as well moves only the common factor of every
    term, which a free swing does not tell."""
    scales = ["pole_inertia_scale", "pole2_inertia_scale", "pole3_inertia_scale"]
    m1, m2, m3 = stages.MULTIARM_MASSES_KG[3]
    a2, a3, spacing = 0.2286 / 2, (0.2413 - (0.220 - 0.17272)) / 2, 0.2286
    lines = chain.of("cart-three-pole-swingup", "multiarm_triple_pendulum", ["pole_com_m", *scales]).lines()
    expected = (m2 * a2 + spacing * m3) / (m3 * a3)
    assert lines[0] == f"fixed by the stage: b2 / b3 = {expected:.4g} (no fitted parameter moves it)"
    assert lines[-1].startswith("held at the stage's values: pole_damping_n_m_s_rad, pole_friction_n_m")
    assert chain.of("cart-three-pole-swingup", "multiarm_triple_pendulum",
                    list(multiarm.RIGS[3].fit)).lines() == []
    every = ["pole_com_m", "pole2_com_m", "pole3_com_m", *scales]
    lines = chain.of("cart-three-pole-swingup", "multiarm_triple_pendulum", every).lines()
    assert lines[0].startswith(f"not identifiable together: {', '.join(every)} move the common factor")


def test_values_outside_physical_sense_are_flagged():
    """An inertia scale of 0.0006, a mass 20x the stage's and a centre of mass beyond its arm are flagged; values
    within the bounds are not."""
    env = cartpole_warp.tasks.make("cart-three-pole-swingup", num_envs=1, device="cpu",
                                   preset="multiarm_triple_pendulum")
    stage = {name: float(v[0]) for name, v in env.physics.stage_values().items()}
    fitted = {"pole_inertia_scale": 0.0006, "pole2_inertia_scale": 1.4, "pole_mass_kg": 20 * stage["pole_mass_kg"],
              "pole2_mass_kg": stage["pole2_mass_kg"], "pole_com_m": 2.5 * stage["pole_com_m"],
              "pole2_com_m": 1.8 * stage["pole2_com_m"]}
    flags = sysid.implausible(fitted, stage, env.physics.table)
    assert sorted(flags) == ["pole_com_m", "pole_inertia_scale", "pole_mass_kg"]
    assert flags["pole_inertia_scale"].startswith("0.0006x the stage's")
    env.close()


def test_a_fit_that_no_step_improves_ends_as_stalled(tmp_path, capsys):
    """With --tolerance 0 Gauss-Newton's test never holds on a noisy recording; once no step lowers the loss with
    Levenberg-Marquardt's damping at its largest, the fit ends, saying so, instead of repeating one Jacobian to the
    budget."""
    path = free_swings(tmp_path / "swing.npz", HIDDEN, [1.2, 0.5], seconds=1.0)
    recording = dict(np.load(path))
    recording["pole_angle_rad"] += np.random.default_rng(0).normal(0.0, 1e-3, len(recording["time_s"]))
    np.savez(path, **recording)
    earlier = tmp_path / "earlier.yaml"
    earlier.write_text(multiarm.yaml.safe_dump({"task": "cartpole-swingup", "fitted": HIDDEN}))
    result = sysid.fit(sysid.SysidArgs(
        trajectory=path, task="cartpole-swingup", config="multiarm_pendulum", window_steps=[200], window_stride=2,
        guesses=1, iterations=60, tolerance=0.0, start_from=earlier, output=tmp_path / "fit"))
    (stage,) = result["iterations"]
    assert stage["stalled"] and not stage["converged"] and stage["iterations"] < 60, stage
    assert f"stalled after {stage['iterations']} iterations: no step lowers the loss" in capsys.readouterr().out


def test_a_fit_starts_from_an_earlier_result(tmp_path):
    """``--from`` an earlier result that holds the hidden physics: one iteration keeps it within 0.5% and finds the
    fit converged, where one iteration from the stage is more than 1% off and not converged; an earlier fit of
    another task, or one whose parameters ``--fit`` leaves out, is one line."""
    path = free_swings(tmp_path / "swing.npz", HIDDEN, [1.2, 0.5], seconds=1.0)
    earlier = tmp_path / "earlier.yaml"
    earlier.write_text(multiarm.yaml.safe_dump({"task": "cartpole-swingup", "fitted": HIDDEN}))
    args = dict(trajectory=path, task="cartpole-swingup", config="multiarm_pendulum", window_steps=[200],
                window_stride=2, guesses=1, iterations=1)
    started = sysid.fit(sysid.SysidArgs(**args, start_from=earlier, output=tmp_path / "started"))
    assert sorted(started["fitted"]) == sorted(HIDDEN), "without --fit: the earlier fit's parameter list"
    for name, value in HIDDEN.items():
        assert started["fitted"][name] == pytest.approx(value, rel=0.005), name
    assert started["iterations"] == [{"window_steps": 200, "iterations": 1, "converged": True, "stalled": False,
                                      "predicted_fall": started["iterations"][0]["predicted_fall"]}]
    cold = sysid.fit(sysid.SysidArgs(**args, fit=list(HIDDEN), output=tmp_path / "cold"))
    assert abs(cold["fitted"]["pole_inertia_scale"] / HIDDEN["pole_inertia_scale"] - 1) > 0.01
    assert not cold["iterations"][0]["converged"]
    earlier.write_text(multiarm.yaml.safe_dump({"task": "cart-two-pole-swingup", "fitted": HIDDEN}))
    with pytest.raises(ConfigError, match="is a fit of --task cart-two-pole-swingup, not of cartpole-swingup"):
        sysid.fit(sysid.SysidArgs(**args, start_from=earlier))
    earlier.write_text(multiarm.yaml.safe_dump({"task": "cartpole-swingup", "fitted": HIDDEN}))
    with pytest.raises(ConfigError, match="fitted pole_friction_n_m, which --fit leaves out"):
        sysid.fit(sysid.SysidArgs(**args, start_from=earlier, fit=["pole_inertia_scale", "pole_damping_n_m_s_rad"]))


def test_a_preset_works_from_another_folder(tmp_path, monkeypatch):
    """A preset beside its own stage (a relative ``stage_path``) builds its env from any working folder, and the
    preset a fit writes from it does too, wherever it is read from."""
    rig = tmp_path / "rig"
    rig.mkdir()
    (rig / "my_arm.usda").write_text(data_path("usd", "multiarm_pendulum.usda").read_text())
    preset = (data_path("configs", "multiarm_pendulum.yaml").read_text()
              .replace("stage_path: multiarm_pendulum.usda", "stage_path: my_arm.usda"))
    assert "my_arm.usda" in preset
    (rig / "arm.yaml").write_text(preset)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    env = cartpole_warp.tasks.make("cartpole-swingup", num_envs=1, device="cpu", preset=str(rig / "arm.yaml"))
    assert Path(env.stage_path) == rig / "my_arm.usda"
    env.close()
    args = sysid.SysidArgs(trajectory=tmp_path / "swing.npz", task="cartpole-swingup", config=str(rig / "arm.yaml"))
    written = sysid.write_preset(tmp_path / "fit" / "sysid_preset.yaml", args, {"pole_inertia_scale": 1.0},
                                 {"pole_inertia_scale": 1.3}, env.physics.table)
    monkeypatch.chdir(rig)
    env = cartpole_warp.tasks.make("cartpole-swingup", num_envs=1, device="cpu", preset=str(written))
    assert Path(env.stage_path) == rig / "my_arm.usda"
    env.close()


HIDDEN_THREE = {"pole_com_m": 0.11, "pole2_com_m": 0.16, "pole3_com_m": 0.15, "pole_inertia_scale": 1.3,
                "pole2_inertia_scale": 1.5, "pole_friction_n_m": 8e-4, "pole2_friction_n_m": 6e-4,
                "pole3_friction_n_m": 2e-4}
"""Three arms' hidden physics: centres of mass 27-55% beyond the stage's (their hubs), inertias 30-50% above the
boxes', Coulomb friction in every joint."""


@pytest.mark.slow
def test_the_documented_triple_fit_recovers_a_synthetic_swing(tmp_path):
    """A free swing of the three-arm rig recorded by the env at 1 kHz on hidden physics is fitted back within 1%
    from the stage's values by the fit ``tools.multiarm --arms 3`` runs (its parameter list, windows and budget), its
    last window length converged or stalled at the rollouts' resolution; the dampings, 0 in the recording, stay near
    0: at 1 rad/s under 1% of their joint's friction. The swings stay below chaos (with a chaotic one, from 2 rad,
    the fit's last digits, and so arm 1's friction against its damping, differed between an AMD and an Intel CPU)."""
    path = free_swings(tmp_path / "three.npz", HIDDEN_THREE, [(1.0, 0.4, -0.3), (-0.6, 0.8, 0.5), (0.3, -0.2, 0.2)],
                       seconds=4.0, arms=3)
    defaults, rig = multiarm.MultiarmArgs(), multiarm.RIGS[3]
    result = sysid.fit(sysid.SysidArgs(
        trajectory=path, task=rig.task, config=rig.preset, fit=list(rig.fit), window_steps=defaults.window_steps,
        window_stride=defaults.window_stride, guesses=defaults.guesses, iterations=defaults.iterations,
        tolerance=defaults.tolerance, output=tmp_path / "fit"))
    last = result["iterations"][-1]  # the 100-step windows bring the fit near, the 500-step ones end it
    assert last["window_steps"] == 500 and (last["converged"] or last["stalled"]), result["iterations"]
    for name, value in HIDDEN_THREE.items():
        assert result["fitted"][name] == pytest.approx(value, rel=0.01), name
    for k in ("", "2", "3"):
        assert result["fitted"][f"pole{k}_damping_n_m_s_rad"] * 1.0 < 0.01 * HIDDEN_THREE[f"pole{k}_friction_n_m"]
