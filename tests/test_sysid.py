"""System identification (``tools.sysid``): a recording made on hidden physics (the env's own step, every mass and
the pole's centre of mass 15-25% off the stage's) is fitted back, the preset it writes trains on the fitted physics,
and play.py's recording format reads back as written."""

import numpy as np
import pytest
import torch
import yaml

import cartpole_warp
from cartpole_warp.evaluation.trajectories import Recording, TrajectoryRecorder, read_trajectory, write_trajectory
from cartpole_warp.rl.config import train_config
from cartpole_warp.settings.config import ConfigError
from cartpole_warp.tools import sysid

HIDDEN = {"cart_mass_kg": 1.2, "pole_mass_kg": 0.085, "pole_com_m": 0.42}
"""The swing-up's physics off its stage's (1 kg, 0.1 kg, 0.5 m)."""


def record(path, seconds: float = 4.0, noise: float = 0.0) -> Recording:
    """The swing-up on HIDDEN physics under two sines, env 0 recorded by play.py's recorder."""
    env = cartpole_warp.tasks.make("cartpole-swingup", num_envs=1, device="cpu")
    env.set_physical_params(**{name: torch.tensor([value]) for name, value in HIDDEN.items()})
    recorder = TrajectoryRecorder(env)
    env.reset(seed=0)
    recorder(0)
    t = np.arange(int(round(seconds / env.env_dt))) * env.env_dt
    actions = 0.3 * np.sin(2 * np.pi * 1.3 * t) + 0.15 * np.sin(2 * np.pi * 3.1 * t + 1.0)
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
    args = sysid.SysidArgs(trajectory=path, task="cartpole-swingup", fit=list(HIDDEN), window_steps=20, guesses=2,
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


@pytest.mark.slow
def test_noisy_positions_give_standard_errors_that_cover_the_fit(tmp_path):
    """1% noise on the positions: each parameter's fit lies within three of its standard errors of the truth."""
    path = tmp_path / "rig.npz"
    record(path, seconds=6.0, noise=0.01)
    result = sysid.fit(sysid.SysidArgs(trajectory=path, task="cartpole-swingup", fit=list(HIDDEN), window_steps=50,
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
