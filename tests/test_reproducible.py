"""Same seed, same run: two ``train.py --seed 1`` runs give bitwise the same weights, optimizer state and per-iteration
statistics. On the CPU always; on a GPU with ``CARTPOLE_TEST_DEVICE=cuda:0 pytest tests/test_reproducible.py`` (CUDA
graphs on, SyncFreePPO, Featherstone: the defaults), on both of SolverFeatherstone's paths (``sim.tile_gemm``)."""

import subprocess
import sys
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parent.parent
TIMING_KEYS = ("train_time_s", "env_steps_per_s", "collection_ms", "learning_ms")
"""Per-iteration entries that measure the clock, not the run (and an evaluation's 'seconds')."""


def train(device: str, log_dir: Path, iterations: int, num_envs: int, tile_gemm: str) -> tuple[dict, list[dict]]:
    """One seeded run on SolverFeatherstone's path ``tile_gemm``: (its final checkpoint, its per-iteration history
    without clock readings)."""
    result = subprocess.run([sys.executable, str(REPO / "train.py"), "--device", device, "--seed", "1",
                             "--env.sim.tile-gemm", tile_gemm,
                             "--num-envs", str(num_envs), "--max-iterations", str(iterations), "--logger", "none",
                             "--log-dir", str(log_dir)], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    (checkpoint,) = log_dir.rglob(f"model_{iterations - 1}.pt")
    saved = torch.load(checkpoint, map_location="cpu", weights_only=False)
    history = [{k: v for k, v in entry.items() if k not in TIMING_KEYS} for entry in saved["infos"]["history"]]
    for entry in history:
        entry.get("evaluation", {}).pop("seconds", None)
    return saved, history


def tensors(tree, prefix="") -> dict[str, torch.Tensor]:
    """Every tensor in a nested checkpoint dict, by its path."""
    if isinstance(tree, torch.Tensor):
        return {prefix: tree}
    if isinstance(tree, dict):
        return {k: v for key, value in tree.items() for k, v in tensors(value, f"{prefix}/{key}").items()}
    if isinstance(tree, (list, tuple)):
        return {k: v for i, value in enumerate(tree) for k, v in tensors(value, f"{prefix}/{i}").items()}
    return {}


@pytest.mark.parametrize("tile_gemm", ["off", "on"])
def test_same_seed_same_run(device, tmp_path, tile_gemm):
    iterations, num_envs = (40, 4096) if device.startswith("cuda") else (6, 256)
    first, first_history = train(device, tmp_path / "a", iterations, num_envs, tile_gemm)
    second, second_history = train(device, tmp_path / "b", iterations, num_envs, tile_gemm)
    assert len(first_history) == iterations and first_history == second_history
    a, b = tensors(first), tensors(second)
    assert a.keys() == b.keys() and len(a) > 10
    for name in a:
        assert torch.equal(a[name], b[name]), f"{name} differs"


def test_on_a_gpu(device):
    """Where the suite runs on the CPU, say how to run the GPU check (CI has no GPU)."""
    if not device.startswith("cuda"):
        pytest.skip("needs a GPU: CARTPOLE_TEST_DEVICE=cuda:0 python -m pytest tests/test_reproducible.py")
    assert torch.cuda.is_available(), f"CARTPOLE_TEST_DEVICE={device}, but torch sees no GPU"
