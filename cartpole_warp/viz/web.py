"""Newton's ``ViewerViser`` on the batched env: a web page served by this process, the first envs in a grid, live
plots of the reward per step and the episode length, pause and single-step from the page (of the env steps in
play.py, of the iterations while training).

Needs the viser extra: ``pip install 'cartpole_warp[viser]'``. Binds to 127.0.0.1 unless told another host: anyone who
can reach the host and port sees the page and can pause the run. ``Recording`` writes a ``.viser`` file, and
``python -m cartpole_warp.viz.web FILE.viser`` plays one in viser's static player.
"""

from __future__ import annotations

import collections
import contextlib
import http.server
import io
import math
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import newton
import numpy as np
import torch
import warp as wp

from ..engine.env import BatchedEnv
from ..evaluation.statistics import METRIC_LABELS, EpisodeStats, EpisodeSummary
from . import ViewerUnavailable, prepare_viewers
from .frames import env_bounds

VISER_EXTRA = "pip install 'cartpole_warp[viser]'"
MARGIN_M = 0.5
"""Space around each env's reach (m)."""
CAMERA_FOV_DEG = 50.0
"""Vertical field of view assumed when framing the grid (viser's default is near it)."""
MIN_ASPECT = 0.85
"""The narrowest view (width / height) the grid is framed for, so that no env is cut off: a page beside its panel is
mostly wider than tall."""
PLOTS = (("reward per step", "#2563eb"), ("episode length (s)", "#ea580c"))
"""The page's plots: name, line colour."""
PLOT_POINTS = 500
"""Points each plot keeps (the latest)."""
PLOT_REFRESH_S = 0.5
"""The plots are sent to the page at most this often (each refresh makes the browser redraw them)."""
RECORDING_NAME = "recording.viser"
"""The recording's address on the player's server."""


def check_viser():
    """ViewerUnavailable naming the install command unless viser is installed."""
    try:
        import viser  # noqa: F401
    except ImportError:
        raise ViewerUnavailable(f"the browser viewer needs the viser extra: {VISER_EXTRA}") from None


class Panel:
    """The page's own panel, in place of Newton's generic one (cloth, particles, contacts): what runs (``status``
    markdown), Pause and Step, and one plot per ``PLOTS`` entry against ``x_label`` with labelled axes."""

    def __init__(self, server, x_label: str, paused: bool):
        from viser import uplot

        server.gui.reset()
        server.gui.configure_theme(control_layout="fixed", control_width="medium", show_logo=False)
        self.status = server.gui.add_markdown("")
        self.pause = server.gui.add_checkbox("Pause", initial_value=paused)
        self.step = server.gui.add_button("Step", disabled=not paused)
        self._step_requested = False

        @self.pause.on_update
        def _on_pause(_event):
            self.step.disabled = not self.pause.value

        @self.step.on_click
        def _on_step(_event):
            self._step_requested = True

        self.points = {name: collections.deque(maxlen=PLOT_POINTS) for name, _ in PLOTS}
        self.plots = {name: server.gui.add_uplot(
            data=(np.zeros(0), np.zeros(0)),
            series=(uplot.Series(label=x_label), uplot.Series(label=name, stroke=colour, width=2)),
            scales={"x": uplot.Scale(time=False, auto=True), "y": uplot.Scale(auto=True)},
            axes=(uplot.Axis(label=x_label), uplot.Axis(label=name, size=60)),
            legend=uplot.Legend(show=False), aspect=1.5) for name, colour in PLOTS}
        self._refreshed, self._unsent = -math.inf, False

    def wants_step(self) -> bool:
        """Whether to go on: not paused, or Step was pressed since the last call."""
        if not self.pause.value:
            return True
        requested, self._step_requested = self._step_requested, False
        return requested

    def update(self, status: str, x: float, values: dict[str, float]):
        """Show ``status`` and add the points (``x``, value) of the named plots (sent at most every
        ``PLOT_REFRESH_S``)."""
        if self.status.content != status:
            self.status.content = status
        for name, value in values.items():
            self.points[name].append((x, value))
        self._unsent = self._unsent or bool(values)
        now = time.perf_counter()
        if self._unsent and now - self._refreshed >= PLOT_REFRESH_S:
            self._refreshed, self._unsent = now, False
            for name, points in self.points.items():
                if points:
                    self.plots[name].data = tuple(np.array(column, dtype=np.float64) for column in zip(*points))


class WebViewer:
    """The first ``num_shown`` envs of ``env`` in Newton's viser viewer at ``http://host:port``, with this project's
    panel (``Panel``): ``title`` (the task), plots against ``x_label``."""

    def __init__(self, env: BatchedEnv, host: str = "127.0.0.1", port: int = 8080, num_shown: int = 16,
                 title: str = "cartpole_warp", x_label: str = "time (s)", paused: bool = False,
                 play_metric: str = "time_limit_fraction"):
        check_viser()
        from newton.viewer import ViewerViser

        self.env, self.play_metric = env, play_metric
        prepare_viewers()
        self.viewer = ViewerViser(host=host, port=port, label=title, verbose=False, paused=False)
        self.url = self.viewer.url
        self.panel = Panel(self.viewer.server, x_label, paused)
        model = env.scene.model
        self.num_shown = min(num_shown, env.scene.num_envs)
        self.viewer.set_model(model)
        self.viewer.set_visible_worlds(range(self.num_shown))
        low, high = env_bounds(env)
        width_m, height_m = high - low + 2 * MARGIN_M
        spacing = (0.0, float(width_m), float(height_m))
        self.viewer.set_world_offsets(spacing)
        self._frame_grid(model.up_axis, spacing, (low + high) / 2)
        self._shown = wp.array(model.articulation_world.numpy() < self.num_shown, dtype=wp.bool, device=model.device)

    @property
    def shown(self) -> str:
        """Which envs the page shows, in words."""
        return f"envs 0-{self.num_shown - 1} of {self.env.num_envs:,} shown"

    def ended(self, summary: EpisodeSummary) -> str:
        """How many episodes ``summary`` counts and the task's play metric over them: for the share that reached the
        time limit, how many of them did, where the task has one ('' for no episode)."""
        if not summary.episodes:
            return ""
        text = f"; {summary.episodes:,} episodes ended"
        if self.play_metric != "time_limit_fraction":
            value = getattr(summary, self.play_metric)
            return text + f", {METRIC_LABELS[self.play_metric]} {'-' if value is None else f'{value:.3f}'}"
        if self.env.cfg.task.has_time_limit:
            text += f", {round(summary.time_limit_fraction * summary.episodes):,} of them at the time limit"
        return text

    def _frame_grid(self, up_axis, spacing: tuple[float, float, float], env_centre: np.ndarray):
        """Camera side-on (looking along -X), far enough to see every shown env's reach."""
        offsets = newton.utils.compute_world_offsets(self.num_shown, spacing, up_axis)
        width_m = np.ptp(offsets[:, 1]) + spacing[1]
        height_m = np.ptp(offsets[:, 2]) + spacing[2]
        distance_m = max(height_m, width_m / MIN_ASPECT) / (2 * math.tan(math.radians(CAMERA_FOV_DEG) / 2))
        centre = offsets.mean(axis=0)
        self.viewer.set_camera(wp.vec3(distance_m, float(centre[1] + env_centre[0]), float(centre[2] + env_centre[1])),
                               pitch=0.0, yaw=180.0)

    def is_running(self) -> bool:
        return self.viewer.is_running()

    def wants_step(self) -> bool:
        """Whether the env should step now: not paused, or the page asked for one step."""
        return self.panel.wants_step()

    def draw(self, x: float, status: str, scalars: dict[str, float] | None = None):
        """The shown envs' current poses (resets included), the panel's ``status`` and the named scalars' points at
        ``x``."""
        state = self.env.scene.state_0
        newton.eval_fk(self.env.scene.model, state.joint_q, state.joint_qd, state, mask=self._shown)
        self.viewer.begin_frame(x)
        self.viewer.log_state(state)
        self.viewer.end_frame()
        self.panel.update(status, x, scalars or {})

    def close(self):
        """Stop the server (its port is free afterwards)."""
        self.viewer.close()


@contextlib.contextmanager
def ctrl_c_interrupts():
    """Ctrl-C (SIGINT) raises ``KeyboardInterrupt`` inside, also in a process started with SIGINT ignored (a
    background job's, a pytest-xdist worker's children): the viewers end on Ctrl-C as training does. Outside the main
    thread (where Python allows no handler) nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def view_in_browser(env: BatchedEnv, policy: Callable[[torch.Tensor], torch.Tensor], host: str, port: int,
                    num_shown: int, max_steps: int | None = None, on_ready: Callable[[str], None] = print,
                    title: str = "cartpole_warp", play_metric: str = "time_limit_fraction") -> int:
    """Run ``policy`` in the browser viewer at real time until Ctrl-C (or ``max_steps`` env steps); return the steps
    run. ``on_ready(url)`` is called once the page is served; ``title``: the task; ``play_metric``: its play metric
    (the page shows it)."""
    viewer = WebViewer(env, host, port, num_shown, title=title, play_metric=play_metric)
    on_ready(viewer.url)
    obs, _ = env.reset()
    steps, stats = 0, EpisodeStats(env.device, env.max_episode_length)
    try:
        with torch.inference_mode(), ctrl_c_interrupts():
            while viewer.is_running() and (max_steps is None or steps < max_steps):
                started = time.perf_counter()
                points = {}
                if viewer.wants_step():
                    obs, reward, terminated, truncated, info = env.step(policy(obs).to(torch.float32))
                    steps += 1
                    ended = terminated | truncated
                    points["reward per step"] = reward.mean().item()
                    stats.add(ended, info["episode_return"], info["episode_length"], truncated)
                    if ended.any():
                        points["episode length (s)"] = info["episode_length"][ended].float().mean().item() * env.env_dt
                status = f"**{title}**, playing: t = {steps * env.env_dt:.2f} s, {viewer.shown}"
                viewer.draw(steps * env.env_dt, status + viewer.ended(stats.summary()), points)
                time.sleep(max(0.0, env.env_dt - (time.perf_counter() - started)))
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()
    return steps


class TrainingView:
    """``TrainingLoop.on_iteration``: the training envs in the browser viewer, drawn between iterations at most every
    ``interval_s`` seconds and while drawing takes at most ``1 / (1 + DRAW_RATIO)`` of the wall time (each draw waits
    ``DRAW_RATIO`` times the last draw's duration); the plots show each drawn iteration's mean reward per step and
    episode length. Each update makes the browser render: one that renders in software on the training's own cores
    (no GPU) spends most of a core-second on it. The page's Pause holds training after the iteration in progress (its
    Step lets one more iteration through) until it is unchecked, the server closes or ``stopping()`` says a stop was
    requested (Ctrl-C)."""

    DRAW_RATIO = 20
    POLL_S = 0.05
    """How often a paused training looks at the page."""

    def __init__(self, env: BatchedEnv, host: str, port: int, num_shown: int, interval_s: float = 5.0,
                 stopping: Callable[[], bool] = lambda: False, paused: bool = False, title: str = "cartpole_warp",
                 play_metric: str = "time_limit_fraction"):
        self.viewer = WebViewer(env, host, port, num_shown, title=title, x_label="iteration", paused=paused,
                                play_metric=play_metric)
        self.url, self.title, self.interval_s = self.viewer.url, title, interval_s
        self.stopping = stopping
        self._next_draw = 0.0
        self._last = None
        """(iteration, time) of the last call, for the iteration rate."""

    def __call__(self, iteration: int, summary) -> None:
        started = time.perf_counter()
        rate = (iteration - self._last[0]) / (started - self._last[1]) if self._last else None
        self._last = (iteration, started)
        paused = not self.viewer.wants_step()
        if started >= self._next_draw or paused:
            status = f"**{self.title}**, training: iteration {iteration}, {self.viewer.shown}"
            if rate:
                status += f", {rate:.1f} iterations/s"
            points = {}
            if summary.mean_reward_per_step is not None:
                points = {"reward per step": summary.mean_reward_per_step,
                          "episode length (s)": summary.mean_episode_length * self.viewer.env.env_dt}
            self.viewer.draw(float(iteration), status + self.viewer.ended(summary), points)
            took = time.perf_counter() - started
            self._next_draw = started + max(took * (1 + self.DRAW_RATIO), self.interval_s)
        while paused and self.viewer.is_running() and not self.stopping():
            time.sleep(self.POLL_S)
            paused = not self.viewer.wants_step()

    def close(self):
        self.viewer.close()


class Recording:
    """A ``.viser`` recording of env 0's bodies (what the GIF shows), one frame per env step; ``close()`` writes it.
    Newton's viser viewer records only while it serves, so it serves an unused local port meanwhile."""

    def __init__(self, scene, path: Path, env_dt: float):
        check_viser()
        from newton.viewer import ViewerViser

        self.scene, self.env_dt = scene, env_dt
        prepare_viewers()
        with contextlib.redirect_stdout(io.StringIO()):  # viser prints its address whatever verbose says
            self.viewer = ViewerViser(host="127.0.0.1", port=free_port(), verbose=False, record_to_viser=str(path))
        self.viewer.set_model(scene.model)
        self.viewer.set_visible_worlds([0])

    def __call__(self, step: int):
        self.viewer.begin_frame(step * self.env_dt)
        self.viewer.log_state(self.scene.state_0)
        self.viewer.end_frame()

    def close(self):
        self.viewer.save_recording()
        with contextlib.redirect_stdout(io.StringIO()):  # and that it stopped
            self.viewer.close()


def free_port() -> int:
    """A TCP port nothing listens on now (127.0.0.1)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class PlayerServer(http.server.ThreadingHTTPServer):
    """The static player's server: a browser that leaves mid-transfer (a broken pipe, a reset) is no error to print
    a traceback for."""

    def handle_error(self, request, client_address):
        if not isinstance(sys.exc_info()[1], ConnectionError):
            super().handle_error(request, client_address)


def serve_recording(path: Path, port: int) -> None:
    """Serve viser's static player with the recording ``path`` on 127.0.0.1:``port`` until Ctrl-C."""
    check_viser()
    from newton.viewer import ViewerViser

    data = Path(path).read_bytes()
    client_dir = str(ViewerViser.get_viser_client_dir())

    class Player(http.server.SimpleHTTPRequestHandler):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, directory=client_dir, **kwargs)

        def do_GET(self):
            if self.path == "/":  # the player plays nothing without the recording's address
                self.send_response(302)
                self.send_header("Location", f"/?playbackPath={RECORDING_NAME}")
                self.end_headers()
                return None
            if self.path.split("?")[0] != f"/{RECORDING_NAME}":
                return super().do_GET()
            self.send_response(200)
            self.send_header("Content-Type", "application/octet-stream")
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        def log_message(self, *args):
            pass

    with PlayerServer(("127.0.0.1", port), Player) as server:
        print(f"watch it at http://127.0.0.1:{port}/ (Ctrl-C ends)", flush=True)
        with contextlib.suppress(KeyboardInterrupt), ctrl_c_interrupts():
            server.serve_forever()


def main(argv: list[str] | None = None) -> int:
    """``python -m cartpole_warp.viz.web RECORDING.viser [PORT]``: play a recording in the browser."""
    args = sys.argv[1:] if argv is None else argv
    port = args[1] if len(args) > 1 else "8081"
    if not args or not Path(args[0]).is_file() or len(args) > 2 or not port.isdigit() or not 1 <= int(port) <= 65535:
        print("usage: python -m cartpole_warp.viz.web RECORDING.viser [PORT]  (an existing recording, e.g. "
              "logs/.../play/cartpole.viser; a PORT of 1-65535)", file=sys.stderr)
        return 2
    try:
        serve_recording(Path(args[0]), int(port))
    except ViewerUnavailable as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
