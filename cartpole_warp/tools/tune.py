"""A hyperparameter search on Ray Tune, each trial a population on one device (the tune extra: Ray and Optuna).

    pip install -e '.[tune]'
    python -m cartpole_warp.tools.tune --task cartpole-swingup --device cuda --trials 16 --members 4 \\
        --space "agent.algorithm.learning-rate=loguniform(1e-4,3e-3)" "agent.algorithm.entropy-coef=uniform(0,0.02)" \\
                "agent.actor.hidden-dims=choice(64 64,256 128 64)"
    python -m cartpole_warp.tools.tune ... --address auto          # an existing Ray cluster (``ray start --head``)

A setting of ``--space`` is a train.py flag without its dashes, drawn from ``uniform(low,high)``,
``loguniform(low,high)``, ``randint(low,high)`` (both ends included) or ``choice(a,b,...)`` (an option with spaces is
a list). The settings a population's members may differ in (PPO's, as ``train.py --population.vary`` takes them) are
drawn for each member of a trial; the others (the env, the networks, the rollout) once per trial, shared by its
members. Optuna's sampler (TPE, seeded by ``--seed``) draws them; ASHA stops the trials that lag, reading after each
evaluation the trial's metric: the best of its members' latest evaluations (``--metric``, default the task's play
metric). Each trial trains its members as one population (one process, one batched env, one batched PPO: their
evaluations, verdicts, exports and ordinary run folders, which ``play.py --run`` plays) on its share of the cluster
(``--cpus-per-trial``, ``--gpus-per-trial``: below 1, trials share a GPU). The search's folder holds ``search.md``
(a row per member of each trial), ``search.json``, ``search.png`` (each trial's metric by iteration) and the trials'
folders, ``trial_<id>``; Ray's own records are in its ``ray/``. A trial that fails is reported and the search goes on.
"""

from __future__ import annotations

import datetime
import importlib.util
import io
import json
import re
import sys
from contextlib import redirect_stderr
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import tyro

from .. import tasks
from ..cli import clean_errors, quiet_libraries
from ..evaluation.statistics import EpisodeSummary
from ..rl.learners.batched_ppo.learner import VARIABLE_SETTINGS
from ..rl.population import setting_name
from ..rl.runs import POPULATION_FILE
from ..settings.config import ConfigError, require
from .sweep import variant_flags

DRAWS = ("uniform", "loguniform", "randint", "choice")
SET_BY_THE_SEARCH = ("task", "device", "env.device", "seed", "env.seed", "seeds", "population", "log-dir",
                     "logger", "agent.logger", "max-iterations", "agent.max-iterations", "run-name",
                     "agent.run-name", "resume", "checkpoint")
"""train.py flags (and their prefixes) the search sets for every trial: a --space or --flags entry may not."""
SEARCH_FILES = ("search.md", "search.json", "search.png")


@dataclass
class TuneArgs:
    space: list[str] = field(default_factory=list)
    """The settings to search, each name=draw (module docstring): e.g. 'agent.algorithm.learning-rate=loguniform(1e-4,
    3e-3)'."""
    task: str = tasks.DEFAULT_TASK
    """The registered task every trial trains."""
    trials: int = 8
    """Trials to run (Ray's num_samples)."""
    members: int = 2
    """Members of each trial's population; member k trains with seed --seed + k."""
    seed: int = 0
    """The members' first seed, and the sampler's."""
    device: Literal["cpu", "cuda"] = "cpu"
    """Where each trial trains: cuda is the GPU Ray gives it (its cuda:0)."""
    flags: str = ""
    """train.py flags for every trial, as tools.sweep's variants write them: 'num-envs=1024 eval.num-envs=64'."""
    metric: str | None = None
    """An evaluation's field the search maximises (EpisodeSummary's: mean_return, time_limit_fraction, ...; default
    the task's play metric)."""
    max_iterations: int | None = None
    """Iterations of each trial (default: the task's)."""
    grace_iterations: int | None = None
    """ASHA's grace period: a trial runs this many iterations before it can be stopped (default: a tenth of
    --max-iterations)."""
    reduction_factor: float = 3.0
    """ASHA's reduction factor: at each of its rungs (grace x factor^k iterations) a trial goes on if its metric is in
    the top 1/factor of the trials' there."""
    cpus_per_trial: float = 1.0
    """CPUs Ray reserves for a trial."""
    gpus_per_trial: float = 1.0
    """With --device cuda: GPUs Ray reserves for a trial (0.5: two trials share a GPU)."""
    max_concurrent: int | None = None
    """Trials running at once (default: as many as the cluster's resources hold)."""
    address: str | None = None
    """A running Ray cluster's address ('auto', 'ray://host:10001'); default: a local one, started and stopped here."""
    log_dir: Path = Path("logs/tune")
    """The searches' folder: this search's is <log-dir>/<name>."""
    name: str | None = None
    """The search's name (default: the time and the task)."""


@dataclass(frozen=True)
class Dimension:
    """A setting of the search space: its train.py flag ``name`` (without dashes), its draw (``DRAWS``) and the
    draw's arguments (bounds, or the options of a choice); ``member``: whether each member draws its own."""

    name: str
    draw: str
    values: tuple
    member: bool

    @classmethod
    def parse(cls, entry: str) -> Dimension:
        """A ``--space`` entry; ConfigError in one line for bad syntax, an empty range or a member setting whose
        options are not numbers."""
        match = re.fullmatch(r"\s*([\w.-]+)\s*=\s*(\w+)\((.*)\)\s*", entry)
        if match is None or match.group(2) not in DRAWS:
            raise ConfigError(f"--space {entry!r}: write name=draw, the draw one of uniform(low,high), "
                              "loguniform(low,high), randint(low,high), choice(a,b,...)")
        name, draw = match.group(1), match.group(2)
        options = [option.strip() for option in match.group(3).split(",") if option.strip()]
        member = setting_name(name) in VARIABLE_SETTINGS
        require(options, f"--space {entry!r}: an empty range (no values)")
        if draw == "choice" and not member:
            return cls(name, draw, tuple(options), member)
        try:
            values = tuple((int if draw == "randint" else float)(option) for option in options)
        except ValueError:
            raise ConfigError(f"--space {entry!r}: the values of {draw} must be numbers") from None
        if draw != "choice":
            require(len(values) == 2, f"--space {entry!r}: {draw} takes two bounds, low and high")
            require(values[0] < values[1] or (draw == "randint" and values[0] == values[1]),
                    f"--space {entry!r}: an empty range (low {values[0]:g} >= high {values[1]:g})")
            require(draw != "loguniform" or values[0] > 0, f"--space {entry!r}: loguniform needs low > 0")
        return cls(setting_name(name) if member else name, draw, values, member)

    def domain(self):
        """Ray Tune's search domain of this setting."""
        from ray import tune

        if self.draw == "choice":
            return tune.choice(list(self.values))
        low, high = self.values
        if self.draw == "randint":
            return tune.randint(low, high + 1)  # Ray's excludes its high end
        return {"uniform": tune.uniform, "loguniform": tune.loguniform}[self.draw](low, high)


def check_space(args: TuneArgs) -> tuple[list[str], list[Dimension], int]:
    """train.py's flags for every trial, the space's settings, each checked, and the trials' iterations: ConfigError
    in one line for a flag the search sets, an unknown setting, or a value train.py refuses."""
    from .tune_trial import trial_flags

    dimensions = [Dimension.parse(entry) for entry in args.space]
    require(dimensions, "--space: name at least one setting to search, e.g. "
                        "'agent.algorithm.learning-rate=loguniform(1e-4,3e-3)'")
    names = [dimension.name for dimension in dimensions]
    twice = sorted({name for name in names if names.count(name) > 1})
    require(not twice, f"--space names {', '.join(twice)} twice")
    extra = variant_flags(args.flags)
    for entry, flag in [(d.name, d.name) for d in dimensions] + [("--flags", f[2:]) for f in extra if f[:2] == "--"]:
        set_here = [name for name in SET_BY_THE_SEARCH if flag == name or flag.startswith(name + ".")]
        require(not set_here, f"{entry}: {flag} is set by the search for every trial (the search's own options)")
    base = ["--task", args.task, *extra, "--device", args.device, "--logger", "none",
            *(["--max-iterations", str(args.max_iterations)] if args.max_iterations else [])]
    max_iterations = checked_config(base, f"--flags {args.flags!r}").agent.max_iterations
    for dimension in (d for d in dimensions if not d.member):
        for value in dimension.values:  # a choice's every option, a range's two ends
            checked_config(base + trial_flags({dimension.name: value}), f"--space {dimension.name}={value}")
    return base, dimensions, max_iterations


def checked_config(flags: list[str], what: str):
    """train.py's config of ``flags``; ConfigError in one line, after ``what``, where train.py refuses them."""
    from ..train import resolve_args

    refusal = io.StringIO()
    try:
        with redirect_stderr(refusal):
            return resolve_args(flags)[0]
    except (ConfigError, SystemExit) as err:
        said = str(err) if isinstance(err, ConfigError) else refusal.getvalue().strip().splitlines()[-1]
        raise ConfigError(f"{what}: {said.removeprefix('error: ')}") from None


def search_space(dimensions: list[Dimension], members: int) -> dict:
    """Ray's param_space: the trial's settings under 'trial', member k's under 'member<k>'."""
    shared = {d.name: d.domain() for d in dimensions if not d.member}
    own = {d.name: d.domain() for d in dimensions if d.member}
    return ({"trial": shared} if shared else {}) | ({f"member{k}": dict(own) for k in range(members)} if own else {})


def run_search(args: TuneArgs, base: list[str], dimensions: list[Dimension], metric: str, folder: Path,
               max_iterations: int):
    """The search on Ray (a local cluster unless --address): its ResultGrid."""
    import optuna
    import ray
    from ray import tune
    from ray.tune.search.optuna import OptunaSearch

    from .tune_trial import GracefulASHA, PopulationTrial, SearchLines, StopBoard

    optuna.logging.set_verbosity(optuna.logging.WARNING)

    resources = {"cpu": args.cpus_per_trial, "gpu": args.gpus_per_trial if args.device == "cuda" else 0}
    grace = args.grace_iterations or max(1, max_iterations // 10)
    ray.init(address=args.address, include_dashboard=False, logging_level="warning", log_to_driver=False)
    try:
        board = StopBoard.remote()
        plan = {"flags": base, "seeds": [args.seed + k for k in range(args.members)], "metric": metric,
                "folder": str(folder), "board": board}
        tuner = tune.Tuner(
            tune.with_resources(tune.with_parameters(PopulationTrial, plan=plan), resources),
            param_space=search_space(dimensions, args.members),
            tune_config=tune.TuneConfig(
                metric=metric, mode="max", num_samples=args.trials, max_concurrent_trials=args.max_concurrent,
                search_alg=OptunaSearch(seed=args.seed),
                scheduler=GracefulASHA(board, time_attr="iteration", max_t=max_iterations, grace_period=grace,
                                       reduction_factor=args.reduction_factor)),
            run_config=tune.RunConfig(name="ray", storage_path=str(folder), verbose=0,
                                      callbacks=[SearchLines(metric)],
                                      checkpoint_config=tune.CheckpointConfig(checkpoint_at_end=False),
                                      failure_config=tune.FailureConfig(max_failures=0)))
        return tuner.fit()
    finally:
        ray.shutdown()


def trial_id_of(result) -> str:
    """A Ray result's trial id (its folder's name, ``PopulationTrial_<id>_...``, where it reported nothing)."""
    return result.metrics.get("trial_id") or Path(result.path).name.split("_")[1]


def trial_rows(grid, folder: Path, metric: str) -> list[dict]:
    """A dict per trial of the ResultGrid: its id, status (completed, ``tune_trial.completed``; stopped early;
    failed, and why), settings, metric, history and members (from its population.json where it wrote one), best
    first, failed last."""
    from .tune_trial import completed

    trials = []
    for result in grid:
        trial_id = trial_id_of(result)
        population = folder / f"trial_{trial_id}" / POPULATION_FILE
        rows = json.loads(population.read_text())["members"] if population.is_file() else []
        status = (f"failed: {str(result.error).strip().splitlines()[-1]}" if result.error else
                  "completed" if completed(result.metrics) else "stopped early")
        history = ([] if result.error or result.metrics_dataframe is None or metric not in result.metrics_dataframe
                   else result.metrics_dataframe[["iteration", metric]].dropna().values.tolist())
        latest = result.metrics.get("members", {})
        trials.append({"trial": trial_id, "status": status, "settings": result.config.get("trial", {}),
                       metric: result.metrics.get(metric), "iterations": result.metrics.get("iteration"),
                       "history": history, "folder": str(population.parent),
                       "members": [row | {metric: latest.get(row["member"])} for row in rows]})
    return sorted(trials, key=lambda t: (t["status"].startswith("failed"), -(t[metric] or float("-inf"))))


def search_table(trials: list[dict], metric: str) -> str:
    """search.md: a row per member of each trial (a failed trial's one row says why)."""
    lines = [f"| trial | status | trial's settings | member | member's status | solved at iteration | latest {metric} "
             "| iterations |", "|---|---|---|---|---|---|---|---|"]
    for trial in trials:
        settings = ", ".join(f"{name}={value}" for name, value in trial["settings"].items()) or "-"
        for row in trial["members"] or [{"member": "-"}]:
            value = row.get(metric)
            lines.append(f"| {trial['trial']} | {trial['status']} | {settings} | {row['member']} | "
                         f"{row.get('status', '-')} | "
                         f"{row.get('solved_iterations') or '-'} | {'-' if value is None else f'{value:.3f}'} | "
                         f"{row.get('iterations', '-')} |")
    return "\n".join(lines) + "\n"


def plot_search(trials: list[dict], metric: str, task: str, path: Path):
    """search.png: each trial's metric by iteration, a stopped trial's line dashed."""
    from matplotlib.figure import Figure

    figure = Figure(figsize=(7, 4), layout="constrained")
    axes = figure.subplots()
    for trial in trials:
        if trial["history"]:
            iterations, values = zip(*trial["history"])
            axes.plot(iterations, values, "--" if trial["status"] == "stopped early" else "-", marker="o",
                      markersize=3, label=f"{trial['trial']} ({trial['status']})")
    axes.set(xlabel="iteration", ylabel=f"best member's {metric}", title=f"{task}: {len(trials)} trials")
    if axes.lines:
        axes.legend(fontsize="small")
    figure.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    args = tyro.cli(TuneArgs, args=sys.argv[1:] if argv is None else argv, description=__doc__)
    quiet_libraries()
    with clean_errors(ConfigError):
        missing = [name for name in ("ray", "optuna") if importlib.util.find_spec(name) is None]
        require(not missing, f"tools.tune needs {' and '.join(missing)}: pip install -e '.[tune]'")
        task = tasks.get(args.task)
        metric = args.metric or task.play_metric
        fields = [f for f in EpisodeSummary.__dataclass_fields__ if f not in ("episodes", "full_episodes")]
        require(metric in fields, f"--metric {metric}: an evaluation's fields are {', '.join(fields)}")
        require(args.trials >= 1 and args.members >= 1, "--trials and --members must be >= 1")
        require(args.reduction_factor > 1, f"--reduction-factor must be > 1, got {args.reduction_factor}")
        base, dimensions, max_iterations = check_space(args)
        name = args.name or f"{datetime.datetime.now():%Y-%m-%d_%H-%M-%S}_{args.task}"
        folder = (args.log_dir / name).absolute()
    print(f"search {folder}: {args.trials} trials of {args.members} members of {args.task}, {max_iterations} "
          f"iterations at most, on {args.device}; maximising the best member's {metric}", flush=True)
    grid = run_search(args, base, dimensions, metric, folder, max_iterations)
    trials = trial_rows(grid, folder, metric)
    table = search_table(trials, metric)
    (folder / "search.md").write_text(table)
    (folder / "search.json").write_text(json.dumps(trials, indent=2) + "\n")
    plot_search(trials, metric, args.task, folder / "search.png")
    print(f"\n{table}\n{', '.join(SEARCH_FILES)} in {folder}")
    if (best := next((t for t in trials if not t["status"].startswith("failed") and t["members"]), None)):
        member = max(best["members"], key=lambda row: row[metric] if row[metric] is not None else float("-inf"))
        print(f"best: trial {best['trial']}, {member['member']}: python play.py --headless --run "
              f"{Path(best['folder']) / member['member']}")
    return 0 if any(not t["status"].startswith("failed") for t in trials) else 1


if __name__ == "__main__":
    sys.exit(main())
