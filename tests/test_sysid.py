"""System identification (``tools.sysid``): a recording made on hidden physics (the env's own step, every mass and
the pole's centre of mass 15-25% off the stage's) is fitted back, the preset it writes trains on the fitted physics,
and play.py's recording format reads back as written."""

import numpy as np
import pytest
import torch
import yaml
from test_physics import PHYSICS_DT_S, closed_form_rollout, observed_states, stage_parameters

import cartpole_warp
from cartpole_warp.evaluation.trajectories import Recording, TrajectoryRecorder, read_trajectory, write_trajectory
from cartpole_warp.identification import sysid
from cartpole_warp.rl.config import train_config
from cartpole_warp.settings.config import ConfigError

HIDDEN = {"cart_mass_kg": 1.2, "pole_mass_kg": 0.085, "pole_com_m": 0.42}
"""The swing-up's physics off its stage's (1 kg, 0.1 kg, 0.5 m)."""


def record(path, seconds: float = 4.0, noise: float = 0.0, push_s: float = 0.0) -> Recording:
    """The swing-up on HIDDEN physics under two sines (after ``push_s`` of full push, into the rail's stop), env 0
    recorded by play.py's recorder."""
    env = cartpole_warp.tasks.make("cartpole-swingup", num_envs=1, device="cpu")
    env.set_physical_params(**{name: torch.tensor([value]) for name, value in HIDDEN.items()})
    recorder = TrajectoryRecorder(env)
    env.reset(seed=0)
    recorder(0)
    t = np.arange(int(round(seconds / env.env_dt))) * env.env_dt
    actions = 0.3 * np.sin(2 * np.pi * 1.3 * t) + 0.15 * np.sin(2 * np.pi * 3.1 * t + 1.0)
    actions = np.where(t < push_s, 1.0, actions)
    for k, action in enumerate(actions):
        env.step(torch.tensor([[action]], dtype=torch.float32))
        recorder(k + 1)
    recording = recorder.recording()
    recording.q += noise * np.random.default_rng(0).normal(size=recording.q.shape) * recording.q.std(axis=0)
    recording.qd[:] = np.nan  # positions only: the fit differences them for the windows' first velocities
    write_trajectory(path, recording, env.joint_roles, env.physics.sliders)
    return recording


def test_the_fit_recovers_hidden_masses_and_centre_of_mass_and_its_preset_trains_on_them(tmp_path):
    path = tmp_path / "rig.csv"
    record(path)
    args = sysid.SysidArgs(trajectory=path, task="cartpole-swingup", fit=list(HIDDEN), window_steps=[20], guesses=2,
                           iterations=12, output=tmp_path / "fit")
    result = sysid.fit(args)
    for name, value in HIDDEN.items():
        assert result["fitted"][name] == pytest.approx(value, rel=0.01), name
    assert not result["not_identified"] and max(result["residual_rms"].values()) < 1e-3
    assert (tmp_path / "fit" / "sysid_fit.png").stat().st_size > 10_000
    cfg = train_config("cartpole-swingup", str(tmp_path / "fit" / "sysid_preset.yaml"))
    cfg.env.num_envs = 2
    env = cfg.task_spec.env_class(cfg.env)
    values = env.physical_params()
    for name in HIDDEN:
        assert float(values[name][0]) == pytest.approx(result["fitted"][name], rel=1e-5), name
    moves_as_the_closed_form_with(cfg, result["fitted"])


def moves_as_the_closed_form_with(cfg, fitted: dict):
    """The preset's env (at test_physics' fine time step) follows the closed-form cart-pole of the fitted masses and
    centre of mass (the pole's inertia scaled with its mass, as the env scales it) for 0.5 s of pushes."""
    cfg.env.num_envs = 1
    cfg.env.sim.physics_dt, cfg.env.sim.decimation, cfg.env.sim.mass_matrix_interval = PHYSICS_DT_S, 1, 1
    cfg.env.task.episode_length_s = None
    env = cfg.task_spec.env_class(cfg.env)
    stage = stage_parameters("dmc")
    p = dict(stage, cart_mass=fitted["cart_mass_kg"], pole_mass=fitted["pole_mass_kg"], com_length=fitted["pole_com_m"],
             pole_inertia=stage["pole_inertia"] * fitted["pole_mass_kg"] / stage["pole_mass"])
    start = np.array([0.0, 0.2, np.pi - 0.3, 0.5])
    env.set_state(torch.tensor(start[None], dtype=torch.float32))
    commands = 0.4 * np.sin(2 * np.pi * 1.5 * np.arange(round(0.5 / PHYSICS_DT_S)) * PHYSICS_DT_S)
    trajectory = np.array([env.step(torch.tensor([[c]], dtype=torch.float32))[0][0].numpy() for c in commands])
    reference = closed_form_rollout(start, env.cfg.task.max_push_effort_n * commands, PHYSICS_DT_S, p)
    diff = observed_states(trajectory.astype(np.float64), "cartpole-swingup") - reference
    diff[:, 2] = np.angle(np.exp(1j * diff[:, 2]))
    assert (np.abs(diff).max(axis=0) <= 0.006 * np.abs(reference).max(axis=0) + 2e-3).all()
    stage_physics = closed_form_rollout(start, env.cfg.task.max_push_effort_n * commands, PHYSICS_DT_S, stage)
    assert np.abs(stage_physics - reference).max() > 0.01, "the fitted physics moves otherwise than the stage's"


def test_windows_against_the_rails_stop_are_left_out_and_the_fit_stays_exact(tmp_path, capsys):
    """1.5 s of full push holds the cart against the stage's stop (a stiff spring at 1.8 m): those rows are in no
    window (with them a noise-free fit of the walk-through's recording stalled 2% off), and the rest fits within 1%."""
    path = tmp_path / "rig.npz"
    recording = record(path, seconds=5.5, push_s=1.5)
    assert recording.q[:, 0].max() > 1.75, "the cart reached its stop"
    result = sysid.fit(sysid.SysidArgs(trajectory=path, task="cartpole-swingup", fit=list(HIDDEN), window_steps=[20],
                                       guesses=2, iterations=12, output=tmp_path / "fit"))
    assert "rows lie within 2% of a joint's range of its limit" in capsys.readouterr().out
    near_stop = np.abs(recording.q[:, 0]) > 1.8 - 0.02 * 3.6
    starts = sysid.windows(recording, 20, ~near_stop)
    assert starts and all(not near_stop[s:s + 21].any() for s in starts) and result["windows"] == len(starts)
    for name, value in HIDDEN.items():
        assert result["fitted"][name] == pytest.approx(value, rel=0.01), name


@pytest.mark.slow
def test_noisy_positions_give_standard_errors_that_cover_the_fit(tmp_path):
    """1% noise on the positions: each parameter's fit lies within three of its standard errors of the truth."""
    path = tmp_path / "rig.npz"
    record(path, seconds=6.0, noise=0.01)
    result = sysid.fit(sysid.SysidArgs(trajectory=path, task="cartpole-swingup", fit=list(HIDDEN), window_steps=[50],
                                       guesses=2, iterations=30, output=tmp_path / "fit"))
    for name, value in HIDDEN.items():
        assert abs(result["fitted"][name] - value) < 3 * result["standard_error"][name], name
    written = yaml.safe_load((tmp_path / "fit" / "sysid_result.yaml").read_text())
    assert written["fitted"] == pytest.approx(result["fitted"])


def test_the_recording_format_reads_back_and_names_what_is_missing(tmp_path):
    env = cartpole_warp.tasks.make("cartpole-balance", num_envs=1, device="cpu")
    rows = 5
    recording = Recording(time_s=np.arange(rows) / 60, action=np.linspace(-1, 1, rows)[:, None],
                          q=np.arange(2 * rows, dtype=float).reshape(rows, 2), qd=np.ones((rows, 2)),
                          episode=np.zeros(rows))
    for suffix in (".csv", ".npz"):
        path = write_trajectory(tmp_path / f"t{suffix}", recording, env.joint_roles, env.physics.sliders)
        back = read_trajectory(path, env.joint_roles, env.physics.sliders, 1)
        for field in ("time_s", "action", "q", "qd", "episode"):
            np.testing.assert_allclose(getattr(back, field), getattr(recording, field))
    (tmp_path / "bad.csv").write_text("time_s,action,cart_pos_m\n0,0,0\n")
    with pytest.raises(ConfigError, match="missing columns pole_angle_rad"):
        read_trajectory(tmp_path / "bad.csv", env.joint_roles, env.physics.sliders, 1)
    (tmp_path / "ragged.csv").write_text("time_s,action,cart_pos_m,pole_angle_rad\n0,0,0,zero\n")
    with pytest.raises(ConfigError, match="not a readable trajectory"):
        read_trajectory(tmp_path / "ragged.csv", env.joint_roles, env.physics.sliders, 1)
    header = "time_s,action,cart_pos_m,pole_angle_rad\n"
    for name, body, message in (("nan", "0,0,0,0\n0.1,0,nan,0\n", "positions and actions must be finite"),
                                ("backwards", "0.1,0,0,0\n0.0,0,0,0\n", "time_s must be finite and increase"),
                                ("loud", "0,0,0,0\n0.1,400,0,0\n", r"actions must lie in \[-1, 1\].*largest is 400"),
                                ("empty", "", "expected a header row and data rows")):
        (tmp_path / f"{name}.csv").write_text(header + body)
        with pytest.raises(ConfigError, match=message):
            read_trajectory(tmp_path / f"{name}.csv", env.joint_roles, env.physics.sliders, 1)
    short = write_trajectory(tmp_path / "short.npz", recording, env.joint_roles, env.physics.sliders)
    with pytest.raises(ConfigError, match="no stretch of 21 rows inside one episode"):
        sysid.fit(sysid.SysidArgs(trajectory=short, task="cartpole-balance", window_steps=[20], output=tmp_path / "f"))


def test_plays_multisine_and_random_agents_record_what_they_played(tmp_path, run_main):
    """``play.py --agent multisine`` records the cosines of its docstring (the action applied from each row's time), a
    recording the swing-up's cart makes clear of the rail's stops; ``--agent random`` records uniform actions in
    [-1, 1] that differ step to step."""
    for agent in ("multisine", "random"):
        result = run_main("play", "--headless", "--task", "cartpole-swingup", "--agent", agent, "--num-envs", "2",
                          "--output", tmp_path / agent)
        assert result.returncode == 0, result.stdout + result.stderr
    played = np.load(tmp_path / "multisine" / "trajectory.npz")
    t, actions = played["time_s"][:-1], played["action"][:-1]  # the last row: no action after it
    cosines = (0.5 * np.cos(2 * np.pi * 0.75 * t) + 0.3 * np.cos(2 * np.pi * 1.4 * t)
               + 0.2 * np.cos(2 * np.pi * 2.7 * t))
    assert len(t) == 500 and np.abs(actions - cosines).max() < 1e-6
    assert np.abs(played["cart_pos_m"]).max() < 1.5, "the cart stays off the stops at +-1.8 m"
    random_actions = np.load(tmp_path / "random" / "trajectory.npz")["action"][:-1]
    assert np.abs(random_actions).max() <= 1.0 and random_actions.std() > 0.4 and len(np.unique(random_actions)) > 400
