"""Recorded trajectories of a cart task: the file format that ``tools.sysid`` fits to and ``play.py --headless``
writes (``TrajectoryRecorder``: env 0's steps).

Columns (CSV with a header row, or NPZ): ``time_s``; ``action`` (``action_<i>`` for several), the action applied from
that row's time to the next row's; per joint role its position, ``<role>_pos_m`` for a slider and
``<role>_angle_rad`` for a hinge (relative to the body below it, 0 upright), and optionally its velocity
(``<role>_vel_m_s``, ``<role>_vel_rad_s``); ``episode``, optional, numbers the episodes (a reset starts the next).
"""

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..engine.env import BatchedEnv
from ..settings.config import ConfigError, require

TRAJECTORY_FILE = "trajectory.npz"
"""The file play.py --headless writes env 0's trajectory to."""


@dataclass
class Recording:
    """A trajectory: (T,) times (s), (T, actions) actions, (T, joints) positions and velocities (NaN where not
    recorded), (T,) episode numbers."""

    time_s: np.ndarray
    action: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    episode: np.ndarray


def column_names(roles: tuple[str, ...], sliders: list[bool]) -> tuple[list[str], list[str]]:
    """The position and velocity columns of each joint role."""
    positions = [f"{role}_pos_m" if slider else f"{role}_angle_rad" for role, slider in zip(roles, sliders)]
    velocities = [f"{role}_vel_m_s" if slider else f"{role}_vel_rad_s" for role, slider in zip(roles, sliders)]
    return positions, velocities


def write_trajectory(path: Path, recording: Recording, roles: tuple[str, ...], sliders: list[bool]) -> Path:
    """``recording`` as NPZ or CSV (by ``path``'s suffix), in the columns ``read_trajectory`` takes."""
    positions, velocities = column_names(roles, sliders)
    columns = {"time_s": recording.time_s, "episode": recording.episode}
    columns |= {("action" if recording.action.shape[1] == 1 else f"action_{i}"): recording.action[:, i]
                for i in range(recording.action.shape[1])}
    columns |= {name: recording.q[:, j] for j, name in enumerate(positions)}
    columns |= {name: recording.qd[:, j] for j, name in enumerate(velocities) if np.isfinite(recording.qd[:, j]).all()}
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".npz":
        np.savez(path, **columns)
    else:
        with path.open("w", newline="") as file:
            writer = csv.writer(file)
            writer.writerow(columns)
            writer.writerows(np.stack(list(columns.values()), axis=1).tolist())
    return path


def read_trajectory(path: Path, roles: tuple[str, ...], sliders: list[bool], num_actions: int) -> Recording:
    """The recording in ``path``; ConfigError naming what is missing or malformed."""
    require(path.is_file(), f"no trajectory file {path}")
    try:
        if path.suffix == ".npz":
            with np.load(path) as data:
                columns = {name: np.asarray(data[name], dtype=np.float64).reshape(-1) for name in data.files}
        else:
            with path.open(newline="") as file:
                rows = [row for row in csv.reader(file) if row]
            require(len(rows) > 1, f"{path}: expected a header row and data rows")
            header, values = rows[0], np.array(rows[1:], dtype=np.float64)
            require(values.ndim == 2 and values.shape[1] == len(header),
                    f"{path}: every row needs {len(header)} values, one per header column")
            columns = {name.strip(): values[:, i] for i, name in enumerate(header)}
    except (ValueError, OSError) as err:  # unparsable numbers, ragged rows, not an NPZ
        raise ConfigError(f"{path}: not a readable trajectory ({err})") from None
    require(len({len(column) for column in columns.values()}) == 1, f"{path}: columns of different lengths")
    positions, velocities = column_names(roles, sliders)
    actions = ["action"] if num_actions == 1 else [f"action_{i}" for i in range(num_actions)]
    joints = [name.removesuffix(suffix) for name in columns for suffix in ("_pos_m", "_angle_rad")
              if name.endswith(suffix)]
    mismatch = (f"; its joints ({', '.join(joints)}) are not the task's ({', '.join(roles)})"
                if set(joints) != set(roles) else "")
    missing = [name for name in ["time_s", *actions, *positions] if name not in columns]
    require(not missing, f"{path}: missing columns {', '.join(missing)} (has {', '.join(columns)}){mismatch}")
    require(not mismatch, f"{path}: a recording of more joints than the task's{mismatch}: give the task whose joints "
                          "it recorded")
    length = len(columns["time_s"])
    nan = np.full(length, np.nan)
    recording = Recording(
        time_s=columns["time_s"], action=np.stack([columns[name] for name in actions], axis=1),
        q=np.stack([columns[name] for name in positions], axis=1),
        qd=np.stack([columns.get(name, nan) for name in velocities], axis=1),
        episode=columns.get("episode", np.zeros(length)))
    require(np.isfinite(recording.q).all() and np.isfinite(recording.action).all(),
            f"{path}: positions and actions must be finite")
    largest = float(np.abs(recording.action).max(initial=0.0))
    require(largest <= 1.0 + 1e-6, f"{path}: actions must lie in [-1, 1] (the task's action, before its force "
                                   f"scale); the largest is {largest:g}")
    same_episode = np.diff(recording.episode) == 0
    require(np.isfinite(recording.time_s).all() and (np.diff(recording.time_s)[same_episode] > 0).all(),
            f"{path}: time_s must be finite and increase from row to row within an episode")
    return recording


class TrajectoryRecorder:
    """``on_step(k)`` for a rollout (``evaluation.rollouts``): env 0's joint state after the reset (k = 0) and after
    each step, the action it applied and its episode number; ``recording()`` when done."""

    def __init__(self, env: BatchedEnv):
        self.env = env
        self._q, self._qd, self._actions, self._episodes = [], [], [], []
        self._episode = 0

    def __call__(self, step: int):
        q, qd = self.env.joint_state()
        if step > 0:
            self._actions.append(self.env.buffers.torch.actions[0].cpu().numpy().astype(np.float64))
            torch_views = self.env.buffers.torch
            if bool(torch_views.terminated[0] | torch_views.truncated[0]):
                self._episode += 1
        self._q.append(q[0].cpu().numpy().astype(np.float64))
        self._qd.append(qd[0].cpu().numpy().astype(np.float64))
        self._episodes.append(self._episode)

    def recording(self) -> Recording:
        """The rows so far (the last row's action repeats the one before: no action follows it)."""
        actions = self._actions + self._actions[-1:] if self._actions else [np.zeros(self.env.num_actions)]
        return Recording(time_s=np.arange(len(self._q)) * self.env.env_dt, action=np.array(actions),
                         q=np.array(self._q), qd=np.array(self._qd), episode=np.array(self._episodes, dtype=float))

    def write(self, path: Path) -> Path:
        return write_trajectory(path, self.recording(), self.env.joint_roles, self.env.physics.sliders)
