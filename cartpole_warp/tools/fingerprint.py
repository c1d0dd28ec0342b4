"""The numbers a restructuring must not move: the weights and optimizer states of fixed-seed CPU runs of
``train.py`` (a solo run and a three-member population of the balance and of the swing-up, one SHAC and one
``--learner sapg`` run, each past its first evaluation), as a SHA-256 digest per checkpoint tensor tree. The SHAC run
is named and asked for by the learner's old name, ``apg``, which trees before and after its rename both take.

    python -m cartpole_warp.tools.fingerprint --out after.json                    # this checkout's train.py
    git archive BASE | tar -x -C /tmp/base
    python -m cartpole_warp.tools.fingerprint --tree /tmp/base --out before.json  # another tree, same machine
    python -m cartpole_warp.tools.fingerprint --compare before.json after.json    # exit 1 where any differs

Each run is a fresh ``python <tree>/train.py`` with ``<tree>`` first on the path. CPUs differ in float code, so
compare only fingerprints made on one machine; on one machine the same tree gives the same digests every time.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import torch

from ..cli import clean_errors, parse, quiet_libraries
from ..settings.config import ConfigError, require

COMMON = ["--device", "cpu", "--num-envs", "256", "--max-iterations", "26", "--no-stop-when-solved",
          "--logger", "none", "--agent.save-interval", "1000"]
"""The flags of every run: the CPU, few envs, an evaluation at iteration 25, the checkpoints of the end and the best."""
RUNS = {
    "balance": ["--task", "cartpole-balance"],
    "balance-population": ["--task", "cartpole-balance", "--seeds", "0", "1", "2"],
    "swingup": ["--task", "cartpole-swingup"],
    "swingup-population": ["--task", "cartpole-swingup", "--seeds", "0", "1", "2"],
    "apg": ["--task", "cartpole-balance", "--learner", "apg"],
    "sapg": ["--task", "cartpole-swingup", "--learner", "sapg"],
}
"""The runs by name: train.py's flags beside ``COMMON``."""
REPO = Path(__file__).resolve().parents[2]


class RunFailed(RuntimeError):
    """A run of train.py exited with an error (the message holds its stderr's end)."""


def tensor_digest(value) -> str:
    """SHA-256 of every tensor in a checkpoint's nested dicts and lists (dtype, shape and bytes, in key order); the
    other leaves (iterations, histories with their wall times) are left out."""
    digest = hashlib.sha256()

    def walk(node, path: str):
        if isinstance(node, torch.Tensor):
            flat = node.detach().cpu().contiguous().reshape(-1)
            digest.update(f"{path}|{node.dtype}|{tuple(node.shape)}|".encode())
            digest.update(flat.view(torch.uint8).numpy().tobytes() if flat.numel() else b"")
        elif isinstance(node, dict):
            for key in sorted(node, key=str):
                walk(node[key], f"{path}/{key}")
        elif isinstance(node, (list, tuple)):
            for i, item in enumerate(node):
                walk(item, f"{path}/{i}")

    walk(value, "")
    return digest.hexdigest()


def checkpoint_digests(folder: Path) -> dict[str, str]:
    """``tensor_digest`` of every checkpoint (``*.pt`` but the exports) under a run's or a population's folder, by
    path relative to it."""
    return {str(path.relative_to(folder)): tensor_digest(torch.load(path, map_location="cpu", weights_only=False))
            for path in sorted(folder.rglob("*.pt")) if "exported" not in path.parts}


def fingerprint_run(tree: Path, flags: list[str]) -> dict[str, str]:
    """One run of ``tree``'s train.py with ``flags`` in a fresh process and a temporary log folder: its digests."""
    with tempfile.TemporaryDirectory() as logs:
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(tree), os.environ.get("PYTHONPATH")]))}
        result = subprocess.run([sys.executable, str(tree / "train.py"), *COMMON, *flags, "--log-dir", logs],
                                cwd=tree, env=env, capture_output=True, text=True)
        if result.returncode != 0:
            raise RunFailed(f"train.py {' '.join(flags)} failed ({result.returncode}):\n{result.stderr[-2000:]}")
        (folder,) = Path(logs).glob("rsl_rl/*/*")
        return checkpoint_digests(folder)


def differences(before: dict, after: dict) -> list[str]:
    """What differs between two fingerprints, a line per run (none: bitwise the same)."""
    lines = []
    for run in sorted(before.keys() | after.keys()):
        old, new = before.get(run, {}), after.get(run, {})
        changed = sorted(name for name in old.keys() | new.keys() if old.get(name) != new.get(name))
        if changed:
            lines.append(f"{run}: {', '.join(changed)} differ")
    return lines


@dataclass
class FingerprintArgs:
    out: Path | None = None
    """Write the fingerprint here as JSON (default: print it)."""
    tree: Path = REPO
    """The source tree whose train.py runs (default: this package's checkout)."""
    runs: list[str] = field(default_factory=lambda: list(RUNS))
    """The runs to make (names of ``RUNS``)."""
    compare: tuple[Path, Path] | None = None
    """Compare two fingerprint files instead of running anything: exit 1 where any checkpoint differs."""


def main(argv: list[str] | None = None) -> int:
    quiet_libraries()
    with clean_errors(ConfigError, RunFailed):
        args = parse(FingerprintArgs, FingerprintArgs(), sys.argv[1:] if argv is None else argv, __doc__)
        if args.compare:
            before, after = (json.loads(Path(path).read_text()) for path in args.compare)
            lines = differences(before, after)
            print("\n".join(lines) if lines else f"bitwise the same: {', '.join(sorted(before))}")
            return 1 if lines else 0
        unknown = sorted(set(args.runs) - RUNS.keys())
        require(not unknown, f"unknown runs {', '.join(unknown)}; the runs: {', '.join(RUNS)}")
        require((args.tree / "train.py").is_file(), f"--tree {args.tree} holds no train.py")
        result = {}
        for name in args.runs:
            print(f"{name}: train.py {' '.join(RUNS[name])} ...", flush=True)
            result[name] = fingerprint_run(args.tree, RUNS[name])
        text = json.dumps(result, indent=2) + "\n"
        if args.out:
            args.out.write_text(text)
            print(f"wrote {args.out}")
        else:
            print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
