"""Time to a solved policy, over training settings and seeds: each run is train.py's ``main`` with the run's flags
(optionally followed by ``play --headless`` on its best policy), in this process (one start-up for the whole sweep)
or, with ``--fresh-process``, in a fresh ``python -m cartpole_warp.train`` each; the table says what each setting
costs.

    python -m cartpole_warp.tools.sweep --device cpu --seeds 0 1 2 3 4 \\
        --variants config=default config=isaac_lab "config=default agent.num-steps-per-env=32"
    python -m cartpole_warp.tools.sweep --task cartpole-swingup --device cuda:0 --play
    python -m cartpole_warp.tools.sweep --task cartpole-swingup --device cuda:0 --seeds 0 1 2 3 --population

A variant is train.py's flags written ``name=value`` (or ``name`` for a switch such as ``agent.no-cuda-graph``)
without the dashes, several in one quoted string; a list value is comma-separated (``agent.actor.hidden-dims=64,64``).

It prints two markdown tables. Per seed, as each run ends: the iteration and training seconds at which it was solved,
the milliseconds of one iteration's collection and learning (medians, measured on the device), env-steps/s including
PPO, the evaluations of the whole run and their seconds (part of the training's), the task's play metric
(``Task.play_metric``: the fraction of episodes that reached the time limit for the balance tasks, the reward per step
of full episodes for the swing-up) in the evaluation that decided 'solved', and with ``--play`` the same metric of
play.py's run of the run's best policy, next to it so that the two cannot disagree silently. Per variant, at the end:
the same over the seeds (iterations and seconds as median and worst, play as the worst seed's). A failed run's output
goes to stderr, and it counts as not solved.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import json
import logging
import shlex
import statistics
import subprocess
import sys
import tempfile
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import tyro

from .. import tasks
from ..cli import clean_errors
from ..rl.runs import PLAY_DIR, POPULATION_FILE, SUMMARY_FILE, latest_checkpoint
from ..settings.config import ConfigError, require


@dataclass
class SweepArgs:
    task: str = tasks.DEFAULT_TASK
    """The registered task every run trains."""
    variants: list[str] = field(default_factory=lambda: [""])
    """Settings to measure: train.py flags as name=value pairs (or name for a switch), several in one quoted string
    per variant ('': the task's defaults)."""
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2, 3, 4])
    """Seeds to run every variant with."""
    device: str = "cpu"
    """Device of every run."""
    num_envs: int | None = None
    """Envs of every run (default: each run's own, the task's or its learner's)."""
    max_iterations: int | None = None
    """Iterations of every run (default: the variant's own, 150 for the default settings)."""
    play: bool = False
    """Also run play.py --headless on each result (its best policy; the run's eval.num_envs envs, one time limit)."""
    play_last: bool = False
    """With --play: play each run's last checkpoint instead of its best (does a run keep what it learned?)."""
    stop_when_solved: bool = True
    """End each run when solved, as train.py does by default; --no-stop-when-solved runs each to max_iterations
    (play then judges the best policy the run kept, or with --play-last its last)."""
    log_dir: Path | None = None
    """Keep the runs here (default: a temporary folder)."""
    fresh_process: bool = False
    """Run each training and play in a fresh Python process, as a user's ``python train.py`` does (its start-up
    included in the wall time), instead of in this one, which imports and compiles once for every run."""
    population: bool = False
    """Train each variant's seeds together, as one population (``train.py --seeds``: one process, one batched env;
    a seed's seconds are then the population's until that member's verdict); a variant that cannot train as a
    population (a camera task, ``--learner shac``, ...) runs its seeds one by one, and the sweep says why."""


@dataclass
class RunResult:
    variant: str
    seed: int
    solved_iterations: int | None
    solved_time_s: float | None
    env_steps_per_s: int | None
    collection_ms: float | None = None
    learning_ms: float | None = None
    solved_value: float | None = None
    """The task's play metric in the evaluation that decided 'solved'."""
    play_value: float | None = None
    """The task's play metric of play.py's run of the run's best policy (model_best.pt, else the last; or the last
    with ``--play-last``)."""
    evaluations: int | None = None
    evaluation_s: float | None = None
    """The evaluations' seconds, part of the training's."""
    error: str | None = None
    """The failed command's last output lines (the sweep goes on with the next run)."""


SWEEP_FLAGS = {"task": "--task", "seed": "--seeds", "env.seed": "--seeds", "device": "--device",
               "env.device": "--device", "num-envs": "--num-envs", "env.num-envs": "--num-envs",
               "max-iterations": "--max-iterations", "agent.max-iterations": "--max-iterations",
               "logger": None, "agent.logger": None, "log-dir": "--log-dir", "stop-when-solved": "--stop-when-solved",
               "no-stop-when-solved": "--no-stop-when-solved"}
"""train.py flags the sweep sets for every run (after a variant's, so they would win): a variant may not set them
(the env count and the iterations only where the sweep's --num-envs, --max-iterations are given); the value names
the sweep's own option."""


def variant_flags(variant: str) -> list[str]:
    """train.py flags from ``"name=value name=v1,v2"``."""
    flags = []
    for pair in shlex.split(variant):
        name, sep, value = pair.partition("=")
        flags += [f"--{name}", *(value.split(",") if sep else [])]
    return flags


def run_script(script: str, flags: list[str], fresh_process: bool) -> subprocess.CompletedProcess:
    """``python -m cartpole_warp.<script> <flags>``: in a fresh process, or its ``main(flags)`` in this one with its
    output captured (an exception counts as a failure, its traceback as the output)."""
    if fresh_process:
        return subprocess.run([sys.executable, "-m", f"cartpole_warp.{script}", *flags], capture_output=True, text=True)
    out, err = io.StringIO(), io.StringIO()
    progress = logging.getLogger("cartpole_warp")
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = importlib.import_module(f"cartpole_warp.{script}").main(flags)
    except SystemExit as stop:
        code = stop.code
    except Exception:  # noqa: BLE001 - a failed run is reported and the sweep goes on
        traceback.print_exc(file=err)
        code = 1
    finally:
        progress.handlers.clear()  # bound to this run's captured stdout
    return subprocess.CompletedProcess([script, *flags], code, out.getvalue(), err.getvalue())


def train_flags(args: SweepArgs, variant: str, seeds: list[int], log_dir: Path) -> list[str]:
    """train.py's flags for ``variant`` with one seed (a run) or several (a population)."""
    seed_flags = ["--seed", str(seeds[0])] if len(seeds) == 1 else ["--seeds", *map(str, seeds)]
    return ["--task", args.task, *variant_flags(variant), *seed_flags, "--device", args.device,
            *(["--num-envs", str(args.num_envs)] if args.num_envs else []),
            *(["--max-iterations", str(args.max_iterations)] if args.max_iterations else []),
            "--logger", "none", "--log-dir", str(log_dir),
            "--stop-when-solved" if args.stop_when_solved else "--no-stop-when-solved"]


def run(args: SweepArgs, variant: str, seed: int, log_dir: Path) -> RunResult:
    """One training run (and play); its summary.json is the result."""
    flags = train_flags(args, variant, [seed], log_dir)
    done = run_script("train", flags, args.fresh_process)
    if done.returncode != 0:
        return RunResult(variant, seed, None, None, None,
                         error=f"train.py {' '.join(flags)} failed:\n{done.stdout[-1000:]}\n{done.stderr[-2000:]}")
    run_dir = max(log_dir.rglob(SUMMARY_FILE), key=lambda path: path.stat().st_mtime).parent
    return result_of(args, variant, seed, run_dir)


def run_population(args: SweepArgs, variant: str, log_dir: Path) -> list[RunResult] | str:
    """The variant's seeds as one population (and play on each member's folder): a result per seed, or why the
    variant cannot train as a population (train.py's one line)."""
    flags = train_flags(args, variant, args.seeds, log_dir)
    done = run_script("train", flags, args.fresh_process)
    refusal = done.stderr.strip().removeprefix("error: ")
    if done.returncode == 2 and "population" in refusal and len(refusal.splitlines()) == 1:
        return refusal
    if done.returncode != 0:
        error = f"train.py {' '.join(flags)} failed:\n{done.stdout[-1000:]}\n{done.stderr[-2000:]}"
        return [RunResult(variant, seed, None, None, None, error=error) for seed in args.seeds]
    population = max(log_dir.rglob(POPULATION_FILE), key=lambda path: path.stat().st_mtime).parent
    print(f"population of {_flags_cell(variant)}: {len(args.seeds)} members trained together in "
          f"{json.loads((population / POPULATION_FILE).read_text())['train_time_s']:.1f} s", flush=True)
    members = json.loads((population / POPULATION_FILE).read_text())["members"]
    return [result_of(args, variant, member["seed"], population / member["member"]) for member in members]


def result_of(args: SweepArgs, variant: str, seed: int, run_dir: Path) -> RunResult:
    """A finished run's result from its summary.json (and play.py on it, where ``--play``)."""
    summary = json.loads((run_dir / SUMMARY_FILE).read_text())
    solved = summary["solved_at"] or {}
    result = RunResult(variant, seed, solved.get("iterations"), solved.get("train_time_s"), summary["env_steps_per_s"],
                       summary["collection_ms"], summary["learning_ms"], solved.get(tasks.get(args.task).play_metric),
                       evaluations=summary["evaluations"], evaluation_s=summary["evaluation_s"])
    if args.play:
        last = ["--checkpoint", str(latest_checkpoint(run_dir))] if args.play_last else []
        played = run_script("play", ["--headless", "--run", str(run_dir), *last, "--device", args.device],
                            args.fresh_process)
        if played.returncode != 0:
            result.error = f"play.py on {run_dir} failed:\n{played.stderr[-2000:]}"
            return result
        record = json.loads((run_dir / PLAY_DIR / "result.json").read_text())
        result.play_value = record["play_value"]
    return result


def seed_table_header(task: str) -> str:
    """Markdown header of the per-seed table."""
    metric = tasks.get(task).play_metric
    return ("| train.py flags | seed | solved at iteration | seconds to solved | ms per iteration: collection + "
            f"learning | env-steps/s | evaluations: count, seconds | evaluation at solved: {metric} | "
            f"play: {metric} |\n"
            "|---|---|---|---|---|---|---|---|---|")


def _markdown_row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _flags_cell(variant: str) -> str:
    return f"`{' '.join(variant_flags(variant))}`" if variant.strip() else "(default)"


def _ms_cell(collection_ms: float, learning_ms: float) -> str:
    return f"{collection_ms:.1f} + {learning_ms:.1f}"


def seed_row(result: RunResult) -> str:
    """Markdown row of one run."""
    cells = [_flags_cell(result.variant), str(result.seed)]
    if result.error:
        cells += ["failed"] + ["-"] * 6
    else:
        solved = result.solved_iterations is not None
        cells += [str(result.solved_iterations) if solved else "not solved",
                  f"{result.solved_time_s:.1f}" if solved else "-",
                  _ms_cell(result.collection_ms, result.learning_ms) if result.collection_ms is not None else "-",
                  f"{result.env_steps_per_s:,}" if result.env_steps_per_s else "-",
                  f"{result.evaluations}, {result.evaluation_s:.1f}" if result.evaluations is not None else "-",
                  f"{result.solved_value:.3f}" if result.solved_value is not None else "-",
                  f"{result.play_value:.3f}" if result.play_value is not None else "-"]
    return _markdown_row(cells)


def table(results: list[RunResult], variants: list[str], seeds: int, task: str) -> str:
    """Markdown table: one row per variant (a failed run counts as not solved, and says so)."""
    rows = ["| train.py flags | solved | iterations to solved (median / max) | seconds to solved (median / max) | "
            f"ms per iteration: collection + learning | env-steps/s | play: {tasks.get(task).play_metric} (min) |",
            "|---|---|---|---|---|---|---|"]
    for variant in variants:
        mine = [r for r in results if r.variant == variant]
        solved = [r for r in mine if r.solved_iterations is not None]
        failed = sum(r.error is not None for r in mine)
        speeds = [r.env_steps_per_s for r in mine if r.env_steps_per_s]
        timed = [r for r in mine if r.collection_ms is not None]
        played = [r.play_value for r in mine if r.play_value is not None]
        cells = [_flags_cell(variant), f"{len(solved)}/{seeds}" + (f" ({failed} failed)" if failed else "")]
        if solved:
            iterations, times = [r.solved_iterations for r in solved], [r.solved_time_s for r in solved]
            cells += [f"{statistics.median(iterations):g} / {max(iterations)}",
                      f"{statistics.median(times):.1f} / {max(times):.1f}"]
        else:
            cells += ["-", "-"]
        cells.append(_ms_cell(statistics.median(r.collection_ms for r in timed),
                              statistics.median(r.learning_ms for r in timed)) if timed else "-")
        cells += [f"{statistics.median(speeds):,.0f}" if speeds else "-", f"{min(played):.3f}" if played else "-"]
        rows.append(_markdown_row(cells))
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    args = tyro.cli(SweepArgs, args=sys.argv[1:] if argv is None else argv, description=__doc__)
    results = []
    with clean_errors(ConfigError):
        tasks.get(args.task)
        require(args.seeds and min(args.seeds) >= 0, f"--seeds must be >= 0, got {args.seeds}")
        require(args.num_envs is None or args.num_envs >= 1, f"--num-envs must be >= 1, got {args.num_envs}")
        require(args.max_iterations is None or args.max_iterations >= 1,
                f"--max-iterations must be >= 1, got {args.max_iterations}")
        unset = ({"num-envs", "env.num-envs"} if args.num_envs is None else set()) | (
            {"max-iterations", "agent.max-iterations"} if args.max_iterations is None else set())
        for variant in args.variants:
            for name in (pair.partition("=")[0] for pair in shlex.split(variant)):
                require(name not in SWEEP_FLAGS or name in unset,
                        f"--variants {variant!r}: {name} is set by the sweep for every run"
                        + (f" (use the sweep's {SWEEP_FLAGS[name]})" if SWEEP_FLAGS.get(name) else ""))
    print(seed_table_header(args.task), flush=True)
    with tempfile.TemporaryDirectory() as scratch:
        root = args.log_dir or Path(scratch)
        for number, variant in enumerate(args.variants):
            together = run_population(args, variant, root / f"v{number}_population") if args.population else None
            if isinstance(together, str):
                print(f"{_flags_cell(variant)} cannot train as a population ({together}): its seeds run one by one",
                      flush=True)
            for k, seed in enumerate(args.seeds):
                result = together[k] if isinstance(together, list) else run(args, variant, seed,
                                                                              root / f"v{number}_s{seed}")
                results.append(result)
                if result.error:
                    print(result.error, file=sys.stderr, flush=True)
                print(seed_row(result), flush=True)
    print()
    print(table(results, args.variants, len(args.seeds), args.task))
    return 1 if any(r.error for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
