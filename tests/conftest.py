"""Shared test helpers: small envs with fixed seeds.

Tests run on the CPU; ``CARTPOLE_TEST_DEVICE=cuda:0 pytest`` runs the env tests on a GPU instead.
"""

import os

import torch

import cartpole_warp

DEVICE = os.environ.get("CARTPOLE_TEST_DEVICE", "cpu")


def make(num_envs=64, seed=0, preset="default", **overrides):
    """An env on the test device from a preset with nested overrides (sim={...}, task={...})."""
    return cartpole_warp.make_env(num_envs=num_envs, device=DEVICE, seed=seed, preset=preset, **overrides)


def random_actions(num_envs, steps, seed=0, scale=1.5):
    """A fixed (steps, num_envs, 1) action sequence on the test device, partly outside [-1, 1]."""
    gen = torch.Generator().manual_seed(seed)
    return ((torch.rand((steps, num_envs, 1), generator=gen) * 2 - 1) * scale).to(DEVICE)
