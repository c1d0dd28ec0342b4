"""The multi-arm pendulum benchmark (Kaheman, Fasel, Bramburger, Strom, Kutz, Brunton: "The Experimental Multi-Arm
Pendulum on a Cart: A Benchmark System for Chaos, Learning, and Control", HardwareX 2023, arXiv 2205.06231; data and
code github.com/dynamicslab/MultiArm-Pendulum, MIT licence): ``tools.sysid`` on a real rig's recordings, against the
authors' own model, for each of its three rigs.

    git clone https://github.com/dynamicslab/MultiArm-Pendulum
    python -m cartpole_warp.tools.multiarm --repo MultiArm-Pendulum --arms 1   # writes logs/multiarm/arms1/
    python -m cartpole_warp.tools.multiarm --repo MultiArm-Pendulum --arms 2
    python -m cartpole_warp.tools.multiarm --repo MultiArm-Pendulum --arms 3
    python -m cartpole_warp.tools.multiarm --repo MultiArm-Pendulum --arms 3 \\
        --from logs/multiarm/arms3/fit/sysid_result.yaml   # go on from the last fit

The repository's ``ParameterEstimation/<Single|Double|Triple>Pendulum/*DataForParameterEstimation.mat`` hold free
swings of the arms recorded at 1 kHz with the cart held still, cut into segments: ``Y_id`` to fit, ``Y_vad`` to
validate (per arm its angle from upright, pi hanging, then per arm its angular velocity). Each becomes a recording
of this project (``evaluation.trajectories``: one episode per segment, each pole's angle relative to the arm below,
the cart at 0, no action), written as ``y_id.npz`` and ``y_vad.npz``. ``tools.sysid`` fits the rig's preset
(``configs/multiarm_pendulum.yaml``, ``multiarm_double_pendulum.yaml``, ``multiarm_triple_pendulum.yaml``: the rig's
stage from ``engine.stages``, its cart held) to ``y_id.npz`` alone until it converges, and simulates every segment of
both from its first sample over its whole length. The authors' model (their ``SinglePendulumODE.m``,
``DoublePendulumODE_Mounted.m``, ``TriplePendulumODE_Mounted.m``: ``chain_model``, with their
``EstimatedParameters_*.mat``, integrated by scipy's ``solve_ivp``) predicts the same segments; the table gives each
one's RMS angle error per arm (each arm's angle from upright, as the authors' data give it) for both.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from .. import tasks
from ..cli import clean_errors, parse, quiet_libraries
from ..engine.scene import StageError
from ..evaluation.trajectories import Recording, write_trajectory
from ..identification import chain, sysid
from ..identification.sysid import arm_angles
from ..settings.config import ConfigError, require
from ..settings.files import write_text

SEGMENTS = ("Y_id", "Y_vad")
"""The data file's segment lists: to fit and to validate on."""
ODE_TOLERANCE = 1e-9
"""Relative and absolute tolerance of ``solve_ivp`` on the authors' model (a finer one changes no digit printed)."""


@dataclass(frozen=True)
class Rig:
    """One configuration of the benchmark: its files in the repository, and the task, preset and parameters fitted."""

    folder: str
    data: str
    estimates: str
    task: str
    preset: str
    fit: tuple[str, ...]
    """What a free swing tells (``identification.chain``): each arm's inertia about its hinge and first moment, up to
    one common factor, through 2N - 1 of the N arms' centres of mass and inertia scales, and the joints' damping and
    friction. The masses are the stage's, and one centre or scale is held at the stage's value to fix the factor:
    the top arm's centre of mass where its share of the chain's terms is small (one and two arms), else the top
    arm's inertia scale, a small part of that arm's inertia about its hinge (three arms: holding arm 3's centre
    at the stage's, half the authors' estimate, leaves no physical solution; the fit took arm 1's inertia to 0)."""
    estimate_names: tuple[str, ...]
    """The order of the authors' ``EstimatedParameters``."""


RIGS = {
    1: Rig("SinglePendulum", "SinglePendulumDataForParameterEstimation.mat", "EstimatedParameters_SinglePendulum.mat",
           "cartpole-swingup", "multiarm_pendulum",
           ("pole_inertia_scale", "pole_damping_n_m_s_rad", "pole_friction_n_m"), ("a1", "m1", "I1", "k1", "g")),
    2: Rig("DoublePendulum", "DoublePendulumDataForParameterEstimation.mat", "EstimatedParameters_DoublePendulum.mat",
           "cart-two-pole-swingup", "multiarm_double_pendulum",
           ("pole_com_m", "pole_inertia_scale", "pole2_inertia_scale", "pole_damping_n_m_s_rad",
            "pole2_damping_n_m_s_rad", "pole_friction_n_m", "pole2_friction_n_m"),
           ("m1", "m2", "a1", "a2", "L1", "I1", "I2", "k1", "k2", "g")),
    3: Rig("TriplePendulum", "TriplePendulumDataForParameterEstimation.mat", "EstimatedParameters_TriplePendulum.mat",
           "cart-three-pole-swingup", "multiarm_triple_pendulum",
           ("pole_com_m", "pole2_com_m", "pole3_com_m", "pole_inertia_scale", "pole2_inertia_scale",
            "pole_damping_n_m_s_rad", "pole2_damping_n_m_s_rad", "pole3_damping_n_m_s_rad", "pole_friction_n_m",
            "pole2_friction_n_m", "pole3_friction_n_m"),
           ("m1", "m2", "m3", "a1", "a2", "a3", "L1", "L2", "I1", "I2", "I3", "k1", "k2", "k3", "g")),
}


@dataclass
class MultiarmArgs:
    """Fit the multi-arm pendulum's recordings and compare the prediction with the authors' model (module
    docstring)."""

    repo: Path | None = None
    """A clone of github.com/dynamicslab/MultiArm-Pendulum."""
    arms: int = 1
    """The rig: 1, 2 or 3 arms (the repository's single, double and triple pendulum recordings)."""
    output: Path | None = None
    """Folder for the recordings, the fit (``fit/``) and multiarm_result.yaml (default: logs/multiarm/arms<N>)."""
    window_steps: list[int] = field(default_factory=lambda: [100, 500])
    """Env steps (1 ms each) of the fit's shooting windows: a fit with each in turn (``tools.sysid``)."""
    guesses: int = 1
    """Starting guesses fitted at once (the first: the stage's values)."""
    iterations: int = 60
    """At most this many Levenberg-Marquardt iterations with each window length (a fit ends once converged or
    stalled)."""
    tolerance: float = sysid.SysidArgs.tolerance
    """Converged: a Gauss-Newton step would lower the loss by less than this fraction of it (``tools.sysid``)."""
    start_from: Path | None = None
    """An earlier fit's ``multiarm_result.yaml`` or ``sysid_result.yaml`` (``--from``): its values start the fit."""
    window_stride: int = 4
    """Fit every this-many-th window of ``Y_id`` (1: all)."""
    device: str = "cpu"
    """Where the fit runs: 'cpu' or 'cuda:N'."""


def load_mat(path: Path) -> dict:
    """A MATLAB MAT-file's variables (scipy, the ``sysid`` extra); ConfigError naming a missing file or scipy."""
    try:
        from scipy.io import loadmat
    except ImportError:
        raise ConfigError("reading MAT-files needs scipy: pip install 'cartpole-warp[sysid]'") from None
    require(path.is_file(), f"no file {path}: give --repo a clone of github.com/dynamicslab/MultiArm-Pendulum")
    return loadmat(path)


def read_segments(path: Path, arms: int) -> dict[str, Recording]:
    """The file's ``Y_id`` and ``Y_vad`` as recordings of a cart task with ``arms`` poles (one episode per segment;
    ConfigError where the file is not the benchmark's)."""
    data = load_mat(path)
    missing = [name for name in (*SEGMENTS, "dt") if name not in data]
    require(not missing, f"{path}: missing {', '.join(missing)}: not the benchmark's DataForParameterEstimation file")
    dt = float(np.asarray(data["dt"]).reshape(-1)[0])
    recordings = {}
    for name in SEGMENTS:
        segments = [np.asarray(cell, dtype=np.float64) for cell in np.asarray(data[name]).reshape(-1)]
        require(all(s.ndim == 2 and s.shape[0] == 2 * arms for s in segments),
                f"{path}: {name}'s segments must have {2 * arms} rows (each arm's angle, then each one's velocity)")
        recordings[name] = as_recording(segments, dt, arms)
    return recordings


def as_recording(segments: list[np.ndarray], dt: float, arms: int) -> Recording:
    """Segments of (each arm's angle from upright, then each one's angular velocity) x samples as one recording: the
    cart at rest at 0, each pole's angle relative to the arm below (the joint's), one episode per segment."""
    rows = sum(s.shape[1] for s in segments)
    absolute = np.concatenate([s[:arms].T for s in segments])
    rates = np.concatenate([s[arms:].T for s in segments])
    relative = np.diff(absolute, axis=1, prepend=0.0)
    relative_rates = np.diff(rates, axis=1, prepend=0.0)
    zeros = np.zeros((rows, 1))
    return Recording(time_s=np.concatenate([np.arange(s.shape[1]) * dt for s in segments]),
                     action=zeros, q=np.hstack([zeros, relative]), qd=np.hstack([zeros, relative_rates]),
                     episode=np.concatenate([np.full(s.shape[1], float(k)) for k, s in enumerate(segments)]))


def chain_model(p: dict, arms: int):
    """The authors' equations of motion of ``arms`` arms on their held cart (``SinglePendulumODE.m``,
    ``DoublePendulumODE_Mounted.m``, ``TriplePendulumODE_Mounted.m``: their symbolic toolbox's Lagrangian of the
    chain with viscous joints; state: each arm's angle from upright, then each one's rate) in the chain's matrix form
    (``identification.chain``), ``p`` their ``EstimatedParameters`` by name."""
    terms = p | {f"c{k}": 0.0 for k in range(1, arms + 1)}
    inertia, first, coupling = chain.moments(terms)
    damping, g = np.array([p[f"k{k}"] for k in range(1, arms + 1)]), p["g"]

    def f(_t, y):
        angle, rate = np.asarray(y[:arms]), np.asarray(y[arms:])
        apart = angle[:, None] - angle[None, :]
        mass = np.where(np.eye(arms, dtype=bool), np.diag(inertia), coupling * np.cos(apart))
        torque = -damping * np.diff(rate, prepend=0.0)  # each joint's, on the arm above it; its opposite below
        generalized = torque - np.append(torque[1:], 0.0)
        force = generalized - (coupling * np.sin(apart)) @ rate**2 + g * first * np.sin(angle)
        return np.concatenate([rate, np.linalg.solve(mass, force)])

    return f


def authors_prediction(recording: Recording, arms: int, estimates: dict) -> list[np.ndarray]:
    """Each episode (segment) of ``recording`` simulated by the authors' model from its first sample over its whole
    length, as their objective function does: per episode (samples, arms) angles from upright."""
    from scipy.integrate import solve_ivp

    model = chain_model(estimates, arms)
    out = []
    for episode in np.unique(recording.episode):
        rows = recording.episode == episode
        times = recording.time_s[rows] - recording.time_s[rows][0]
        start = np.concatenate([arm_angles(recording.q[rows][0]), np.cumsum(recording.qd[rows][0, 1:])])
        solution = solve_ivp(model, (0.0, times[-1]), start, t_eval=times, method="DOP853", rtol=ODE_TOLERANCE,
                             atol=ODE_TOLERANCE)
        require(solution.success, f"the authors' model did not integrate: {solution.message}")
        out.append(solution.y[:arms].T)
    return out


def rms_per_arm(predicted: list[np.ndarray], recording: Recording) -> list[list[float]]:
    """Per episode, each arm's RMS angle error (rad) of ``predicted`` against the recorded angles."""
    recorded = arm_angles(recording.q)
    return [np.sqrt(np.mean((p - recorded[recording.episode == episode]) ** 2, axis=0)).tolist()
            for p, episode in zip(predicted, np.unique(recording.episode))]


def fitted_arm_angles(simulated: np.ndarray, recording: Recording) -> list[np.ndarray]:
    """``sysid.predict``'s positions (rows, episodes, joints) as per-episode arm angles."""
    lengths = [int((recording.episode == episode).sum()) for episode in np.unique(recording.episode)]
    return [arm_angles(simulated[:length, e]) for e, length in enumerate(lengths)]


def run(args: MultiarmArgs) -> dict:
    """Convert, fit, predict both ways; print the table and write multiarm_result.yaml. Returns the result."""
    require(args.repo is not None, "--repo DIR is required: a clone of github.com/dynamicslab/MultiArm-Pendulum")
    require(args.arms in RIGS, f"--arms {args.arms}: the repository holds rigs of {', '.join(map(str, RIGS))} arms")
    rig, folder = RIGS[args.arms], args.repo / "ParameterEstimation" / RIGS[args.arms].folder
    output = args.output or Path("logs/multiarm") / f"arms{args.arms}"
    recordings = read_segments(folder / rig.data, args.arms)
    estimates = dict(zip(rig.estimate_names, np.asarray(load_mat(folder / rig.estimates)["EstimatedParameters"])
                         .reshape(-1).tolist()))
    paths = {}
    roles = tasks.get(rig.task).env_class.joint_roles
    for name, recording in recordings.items():
        paths[name] = write_trajectory(output / f"{name.lower()}.npz", recording, roles, [True] + [False] * args.arms)
    fit_args = sysid.SysidArgs(
        trajectory=paths["Y_id"], task=rig.task, config=rig.preset, fit=list(rig.fit), validate=[paths["Y_vad"]],
        window_steps=args.window_steps, window_stride=args.window_stride, guesses=args.guesses,
        iterations=args.iterations, tolerance=args.tolerance, start_from=args.start_from, device=args.device,
        output=output / "fit")
    start = time.perf_counter()
    fitted, positions = sysid.fit_and_predict(fit_args)
    result = {"task": rig.task, "arms": args.arms, "fit_seconds": fitted["seconds"], "total_seconds": 0.0,
              "fitted": fitted["fitted"], "authors_estimates": estimates,
              "what_a_swing_tells": {"ours": chain.invariants(stage_terms(fit_args, fitted["fitted"])),
                                     "authors": chain.invariants(estimates | {f"c{k}": 0.0 for k in
                                                                              range(1, args.arms + 1)})},
              "segments": {}}
    for name, recording in recordings.items():
        result["segments"][name] = [
            {"ours": mine, "authors": theirs} for mine, theirs in
            zip(rms_per_arm(fitted_arm_angles(positions[str(paths[name])], recording), recording),
                rms_per_arm(authors_prediction(recording, args.arms, estimates), recording))]
    result["total_seconds"] = round(time.perf_counter() - start, 1)
    print("what a free swing tells, per arm 1's inertia about its hinge J1 (this fit | the authors' estimates):")
    for key, value in result["what_a_swing_tells"]["ours"].items():
        print(f"  {key:<32} {value:12.5g} | {result['what_a_swing_tells']['authors'][key]:12.5g}")
    table(result)
    write_text(output / "multiarm_result.yaml", yaml.safe_dump(result, sort_keys=False))
    print(f"wrote {output / 'multiarm_result.yaml'}")
    return result


def stage_terms(args: sysid.SysidArgs, fitted: dict) -> dict:
    """The rig's stage with the ``fitted`` physics in the authors' terms (``identification.chain.chain_terms``)."""
    import torch

    env = tasks.make(args.task, num_envs=1, device="cpu", preset=args.config)
    env.set_physical_params(**{name: torch.tensor([value]) for name, value in fitted.items()})
    values = {name: float(v[0]) for name, v in env.physical_params().items()}
    terms = chain.chain_terms(values, env.joint_roles, chain.hinge_spacings(env))
    env.close()
    return terms


def table(result: dict):
    """Each segment's RMS angle error per arm: this project's fit against the authors' model."""
    print("RMS angle error (rad) per segment, each simulated from its first sample over its whole length:")
    print(f"{'segments':<8} {'#':>2} {'this fit (per arm)':>24} {'the authors (per arm)':>24} {'ratio':>14}")
    for name, segments in result["segments"].items():
        for k, errors in enumerate(segments):
            mine, theirs = errors["ours"], errors["authors"]
            ratio = " ".join(f"{m / t:.2f}" for m, t in zip(mine, theirs))
            print(f"{name:<8} {k:>2} {' / '.join(f'{e:.4f}' for e in mine):>24} "
                  f"{' / '.join(f'{e:.4f}' for e in theirs):>24} {ratio:>14}")


def main(argv: list[str] | None = None) -> int:
    quiet_libraries()
    with clean_errors(ConfigError, StageError):
        args = parse(MultiarmArgs, MultiarmArgs(), sys.argv[1:] if argv is None else argv, __doc__,
                     aliases={"--from": "--start-from"})
        run(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
