"""What a free swing of a chain of arms can tell of its physics, and what a fit's parameter list leaves to the stage.

A chain of N arms on a held cart, each arm k with mass m_k, centre of mass a_k above its hinge, inertia I_k about
its centre, its joint's viscous damping k_k and Coulomb friction c_k, hinge k + 1 at L_k above hinge k, moves by
(each arm's angle phi_k from upright; Lagrange's equations)

    sum_j M_kj phi_j'' + sum_j C_kj sin(phi_k - phi_j) phi_j'^2 - g b_k sin(phi_k) = (joint torques)_k,
    M_kk = J_k = I_k + m_k a_k^2 + L_k^2 (m_k+1 + ... + m_N),    M_kj = C_kj cos(phi_k - phi_j),
    b_k = m_k a_k + L_k (m_k+1 + ... + m_N),                    C_kj = L_min(k,j) b_max(k,j),

so the motion holds the 4N terms J_k, b_k, k_k, c_k only up to one common factor (every one times s moves
nothing): a recording tells their ratios, which ``invariants`` names (each per J_1), and the masses of the stage fix
that factor. A fit moves the terms through its parameters; a ratio that no fitted parameter moves is the stage's
(``Identifiability``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .. import tasks

HINGE_ROLES_FROM = 1
"""The chain's joints are the task's roles from this one on (0: the cart)."""
SAME_DIRECTION = 1e-6
"""Two terms whose log-derivatives in every fitted parameter differ by less than this keep their ratio."""


def chain_terms(values: dict[str, float], roles: tuple[str, ...], spacings_m: list[float]) -> dict[str, float]:
    """The chain's terms in the benchmark's letters from a cart task's ``physical_params`` ``values`` (one env's):
    per arm k ``mk``, ``ak``, ``Ik``, ``kk``, ``ck``, the hinge spacings ``Lk`` and ``g``."""
    terms = {"g": values["gravity_m_s2"]}
    for k, role in enumerate(roles[HINGE_ROLES_FROM:], start=1):
        terms |= {f"m{k}": values[f"{role}_mass_kg"], f"a{k}": values[f"{role}_com_m"],
                  f"I{k}": values[f"{role}_inertia_kg_m2"], f"k{k}": values[f"{role}_damping_n_m_s_rad"],
                  f"c{k}": values[f"{role}_friction_n_m"]}
    return terms | {f"L{k}": spacing for k, spacing in enumerate(spacings_m, start=1)}


def hinge_spacings(env) -> list[float]:
    """From each hinge of ``env``'s chain to the next (m): the position of joint k + 1 on the body of arm k."""
    frames = env.scene.model.joint_X_p.numpy()[env.scene.role_joints[HINGE_ROLES_FROM + 1:]]
    return [float(np.linalg.norm(frame[:3])) for frame in frames]


def arms_of(terms: dict) -> int:
    return sum(1 for name in terms if name[0] == "m" and name[1:].isdigit())


def moments(terms: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per arm (from the cart up) J_k and b_k, and the couplings C (N x N, C_kj = L_min b_max, diagonal 0)."""
    n = arms_of(terms)
    m, a, inertia = (np.array([terms[f"{x}{k}"] for k in range(1, n + 1)]) for x in "maI")
    spacing = np.array([terms[f"L{k}"] for k in range(1, n)] + [0.0])
    above = np.cumsum(m[::-1])[::-1] - m  # the mass of the arms above each
    first = m * a + spacing * above
    inertia_about_hinge = inertia + m * a**2 + spacing**2 * above
    low, high = np.minimum.outer(range(n), range(n)), np.maximum.outer(range(n), range(n))
    coupling = np.where(low == high, 0.0, spacing[low] * first[high])
    return inertia_about_hinge, first, coupling


def invariants(terms: dict) -> dict[str, float]:
    """What a free swing tells: the chain's terms per arm 1's inertia about its hinge J1 (module docstring)."""
    n = arms_of(terms)
    inertia, first, coupling = moments(terms)
    j1, g = inertia[0], terms["g"]
    told = {f"J{k + 1} / J1": inertia[k] / j1 for k in range(1, n)}
    told |= {f"g b{k + 1} / J1 (1/s^2)": g * first[k] / j1 for k in range(n)}
    told |= {f"L{i + 1} b{j + 1} / J1": coupling[i, j] / j1 for i in range(n) for j in range(i + 1, n)}
    told |= {f"k{k} / J1 (1/s)": terms[f"k{k}"] / j1 for k in range(1, n + 1)}
    told |= {f"c{k} / J1 (rad/s^2)": terms[f"c{k}"] / j1 for k in range(1, n + 1)}
    return {name: float(value) for name, value in told.items()}


@dataclass
class Identifiability:
    """What a fit's parameter list can move of the ratios a free swing tells (``of``)."""

    fixed: list[tuple[str, str, float]]
    """Ratios of the chain's inertial terms (J_k, b_k) that no fitted parameter moves: (term, term, the stage's
    ratio)."""
    more_fixed: int
    """Further combinations of them fixed by the stage (beyond those ratios)."""
    unseen: list[str]
    """Fitted parameters that together move only the terms' common factor, which no recording tells (empty if
    none)."""
    held: list[str]
    """Joints' damping and friction the fit leaves at the stage's values (named by parameter)."""

    def lines(self) -> list[str]:
        """The report, a line each."""
        out = [f"fixed by the stage: {top} / {bottom} = {ratio:.4g} (no fitted parameter moves it)"
               for top, bottom, ratio in self.fixed]
        if self.more_fixed:
            out.append(f"fixed by the stage: {self.more_fixed} more combination(s) of the arms' J_k and b_k")
        if self.unseen:
            out.append(f"not identifiable together: {', '.join(self.unseen)} move the common factor of every "
                       "term, which a free swing does not tell: keep one at the stage's value")
        if self.held:
            out.append(f"held at the stage's values: {', '.join(self.held)}")
        return out


def of(task: str, config: str | None, fitted: list[str], device: str = "cpu") -> Identifiability | None:
    """The identifiability of ``task``'s chain (under preset ``config``) by a free swing when fitting ``fitted``:
    the log-derivatives of J_k and b_k in each fitted parameter (a forward difference per parameter, one env each),
    at the stage's values. None where the cart is not held (then the cart's mass enters too)."""
    probe = tasks.make(task, num_envs=1 + len(fitted), device=device, preset=config)
    try:
        roles = probe.joint_roles
        if roles[0] not in probe.cfg.sim.held_joints or len(roles) <= HINGE_ROLES_FROM:
            return None
        stage = {name: float(v[0]) for name, v in probe.physics.stage_values().items()}
        step = 1e-4
        moved = {name: torch.full((1 + len(fitted),), stage[name]) for name in fitted}
        for k, name in enumerate(fitted, start=1):
            moved[name][k] = stage[name] * (1 + step) if stage[name] else step
        probe.set_physical_params(**{name: value.to(probe.device) for name, value in moved.items()})
        values = {name: v.cpu().double().numpy() for name, v in probe.physical_params().items()}
        spacings = hinge_spacings(probe)
    finally:
        probe.close()
    per_env = [moments(chain_terms({n: float(v[e]) for n, v in values.items()}, roles, spacings))
               for e in range(1 + len(fitted))]
    logs = np.array([np.log(np.concatenate(moment[:2])) for moment in per_env])  # (1 + P, 2N)
    derivative = (logs[1:] - logs[0]).T  # (2N terms, P): a log-step of a parameter set on the stage, else a unit
    n = len(roles) - HINGE_ROLES_FROM
    names = [f"J{k}" for k in range(1, n + 1)] + [f"b{k}" for k in range(1, n + 1)]
    inertial = np.abs(derivative).max(axis=0) > 0
    return Identifiability(*fixed_ratios(derivative, names, logs[0]),
                           unseen=seen_only_in_scale(derivative[:, inertial], [f for f, i in zip(fitted, inertial)
                                                                              if i]),
                           held=[f"{role}_{kind}" for role in roles[HINGE_ROLES_FROM:]
                                 for kind in ("damping_n_m_s_rad", "friction_n_m") if f"{role}_{kind}" not in fitted])


def fixed_ratios(derivative: np.ndarray, names: list[str], logs: np.ndarray) -> tuple[list, int]:
    """Pairs of terms whose ratio no parameter moves (their rows of ``derivative`` equal), the first of each such
    group against the others, and how many further sum-zero combinations of the log-terms stay fixed."""
    scale = max(float(np.abs(derivative).max(initial=0.0)), 1e-30)
    pairs, grouped = [], set()
    for i in range(len(names)):
        if i in grouped:
            continue
        for j in range(i + 1, len(names)):
            if j not in grouped and np.abs(derivative[i] - derivative[j]).max(initial=0.0) < SAME_DIRECTION * scale:
                pairs.append((names[i], names[j], float(np.exp(logs[i] - logs[j]))))
                grouped.add(j)
    centred = derivative - derivative.mean(axis=0)  # only ratios are told: the common part of a column is unseen
    rank = np.linalg.matrix_rank(centred, tol=SAME_DIRECTION * scale) if derivative.size else 0
    return pairs, max(len(names) - 1 - rank - len(pairs), 0)


def seen_only_in_scale(derivative: np.ndarray, fitted: list[str]) -> list[str]:
    """The fitted parameters of a combination that moves every term by one factor (or none): the parameters a free
    swing cannot tell apart from the masses' scale."""
    if not fitted:
        return []
    centred = derivative - derivative.mean(axis=0)
    _, singular, vectors = np.linalg.svd(centred)
    tol = SAME_DIRECTION * max(float(singular.max(initial=0.0)), 1e-30)
    null = vectors[(np.concatenate([singular, np.zeros(len(fitted) - len(singular))]) <= tol)]
    return [name for name, weight in zip(fitted, np.abs(null).max(axis=0, initial=0.0)) if weight > 1e-3]
