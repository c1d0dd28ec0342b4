"""The browser viewer (viser) in a real browser: headless Chromium driven by Selenium opens the page that
``play.py --viewer viser`` and ``train.py --viewer viser`` serve."""

import io
import os
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import on_all_cores, system_command
from PIL import Image

from cartpole_warp.viz.web import free_port

pytest.importorskip("viser", reason="needs the viser extra: pip install -e '.[viser]'")
webdriver = pytest.importorskip("selenium.webdriver", reason="needs selenium: pip install -e '.[dev]'")

INSTALL = "apt-get install -y chromium chromium-driver"
SCREENSHOT = os.environ.get("CARTPOLE_VISER_SCREENSHOT")
"""Where to keep the page's screenshot (docs/play.md's, docs/images/viser_page.png), if set."""


def port_is_free(port: int) -> bool:
    """Whether a server can listen on ``port`` again (as servers do, with SO_REUSEADDR: the closed connections may
    linger in TIME_WAIT)."""
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
            s.listen()
        except OSError:
            return False
    return True


def ignore_ctrl_c():
    """Start a server as a background job's children start (SIGINT ignored): its Ctrl-C must still end it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def start(repo: Path, script: str, *args) -> tuple[subprocess.Popen, str]:
    """Start ``script`` with ``args`` (``ignore_ctrl_c``); (the process, the URL it prints) once it serves its page."""
    process = subprocess.Popen([sys.executable, str(repo / script), *map(str, args)], cwd=repo, text=True,
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, preexec_fn=ignore_ctrl_c)
    lines = []
    for line in process.stdout:
        lines.append(line)
        found = re.search(r"watch it at (http://\S+)", line)
        if found:
            return process, found.group(1)
    process.wait(timeout=30)
    pytest.fail(f"{script} served no page:\n{''.join(lines)}")


def stop(process: subprocess.Popen) -> str:
    """Ctrl-C the process; its remaining output (it must exit with 0)."""
    process.send_signal(signal.SIGINT)
    try:
        output = process.communicate(timeout=120)[0]
    except subprocess.TimeoutExpired:
        process.kill()
        pytest.fail(f"still running 120 s after Ctrl-C:\n{process.communicate()[0]}")
    assert process.returncode == 0, output
    return output


@pytest.fixture
def browser():
    """Headless Chromium (Debian's, with its chromedriver) with WebGL in software and the console log kept."""
    from selenium.webdriver.chrome.service import Service

    chromium = system_command("chromium", INSTALL)
    driver_path = system_command("chromedriver", INSTALL)
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for argument in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--enable-unsafe-swiftshader",
                     "--use-angle=swiftshader", "--window-size=1280,800"):
        options.add_argument(argument)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    with on_all_cores():  # Chromium draws WebGL in software: on every core, not on this test process's share
        driver = webdriver.Chrome(service=Service(driver_path), options=options)
    yield driver
    driver.quit()


def screenshot(driver) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(driver.get_screenshot_as_png())).convert("RGB")).astype(np.int16)


def open_page(driver, url: str):
    """Load ``url`` and wait for viser's 3-D canvas."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    driver.get(url)
    WebDriverWait(driver, 60).until(lambda d: d.find_elements(By.TAG_NAME, "canvas"))


def console_errors(driver) -> list[str]:
    return [entry["message"] for entry in driver.get_log("browser") if entry["level"] == "SEVERE"]


def test_play_serves_a_moving_scene_to_a_browser(repo, tmp_path, browser):
    """play.py --viewer viser: the page loads without console errors, shows a 3-D canvas, a screenshot that is not
    blank, and another a moment later that differs (the poles move), the project's panel; Ctrl-C frees the port."""
    from selenium.webdriver.common.by import By

    port = free_port()
    process, url = start(repo, "play.py", "--agent", "zero", "--viewer", "viser", "--port", port, "--num-envs", 16,
                         "--steps", 100_000, "--log-dir", tmp_path)
    try:
        assert url == f"http://127.0.0.1:{port}"
        open_page(browser, url)
        time.sleep(4)
        first = screenshot(browser)
        time.sleep(1.5)
        second = screenshot(browser)
        errors = console_errors(browser)
        panel = browser.find_element(By.TAG_NAME, "body").text
        plots = browser.find_elements(By.CLASS_NAME, "uplot")
    finally:
        output = stop(process)
    assert errors == []
    assert "cartpole-balance, playing: t = " in panel and "envs 0-15 of 16 shown" in panel, panel
    assert len(plots) == 2, "the reward per step and the episode length"
    assert "Show Cloth" not in panel and "Contact Forces" not in panel, "the project's panel, not Newton's generic one"
    assert first.std() > 5, "the page is blank"
    assert np.abs(first - second).mean() > 0.01, "the scene does not move"
    assert re.search(r"viewer closed after \d+ env steps", output), output
    assert port_is_free(port)
    if SCREENSHOT:
        Image.fromarray(first.astype(np.uint8)).save(SCREENSHOT)


def test_play_ends_after_its_steps(repo, tmp_path):
    """--steps N ends the browser viewer by itself, with no browser connected."""
    port = free_port()
    result = subprocess.run([sys.executable, str(repo / "play.py"), "--agent", "zero", "--viewer", "viser", "--port",
                             str(port), "--num-envs", "4", "--steps", "30", "--log-dir", str(tmp_path)], cwd=repo,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "viewer closed after 30 env steps" in result.stdout
    assert port_is_free(port)


def test_train_serves_its_envs_and_exits_cleanly(repo, tmp_path, browser):
    """train.py --viewer viser: a short run serves the training envs' page (a 3-D canvas, no console errors), ends
    by itself and frees the port. 200 iterations (~10 s on a 2-core CPU that makes 1.2M env-steps/s, more elsewhere)
    outlast the page's load in headless Chromium; with 40 (~2 s) the run could end before the page's WebSocket
    connected ("ERR_CONNECTION_REFUSED")."""
    port = free_port()
    process, url = start(repo, "train.py", "--num-envs", 64, "--max-iterations", 200, "--no-stop-when-solved",
                         "--viewer", "viser", "--port", port, "--log-dir", tmp_path)
    open_page(browser, url)
    errors = console_errors(browser)
    output = process.communicate(timeout=300)[0]
    assert process.returncode == 0, output
    assert errors == []
    assert "completed: 200 iterations" in output
    assert port_is_free(port)


def test_headless_play_starts_no_viser_server_unless_asked(repo, tmp_path):
    """With the viser extra installed, play.py --headless alone imports no viser (so serves nothing and prints no
    server box) and writes no .viser."""
    code = "import sys; from cartpole_warp.play import main; main(sys.argv[1:]); print('viser' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code, "--agent", "zero", "--headless", "--num-envs", "4", "--steps",
                             "3", "--output", str(tmp_path)], cwd=repo, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0 and result.stdout.splitlines()[-1] == "False", result.stdout + result.stderr
    assert all("viser" not in line.lower() for line in result.stdout.splitlines()[:-1]), result.stdout
    assert not (tmp_path / "cartpole.viser").exists() and (tmp_path / "cartpole.gif").exists()


def test_headless_play_records_for_the_static_player(repo, tmp_path, browser, run_main):
    """play.py --headless --record-viser writes cartpole.viser beside the GIF, for every task; ``python -m
    cartpole_warp.viz.web`` serves it in viser's player at the address it prints, which loads it without console
    errors."""
    from cartpole_warp import tasks

    for task in tasks.names():
        out = tmp_path / task
        result = run_main("play", "--agent", "zero", "--headless", "--task", task, "--num-envs", 4, "--steps", 10,
                          "--output", out, "--record-viser")
        assert result.returncode == 0, result.stdout + result.stderr
        assert (out / "cartpole.viser").stat().st_size > 1000

    port = free_port()
    process = subprocess.Popen([sys.executable, "-m", "cartpole_warp.viz.web",
                                str(tmp_path / tasks.DEFAULT_TASK / "cartpole.viser"), str(port)], cwd=repo,
                               text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, preexec_fn=ignore_ctrl_c)
    try:
        url = re.search(r"watch it at (http://\S+)", process.stdout.readline()).group(1)
        assert url == f"http://127.0.0.1:{port}/", "the address alone plays the recording"
        with urllib.request.urlopen(url) as page:
            assert page.url.endswith("/?playbackPath=recording.viser")
        open_page(browser, url)
        time.sleep(2)
        errors = console_errors(browser)
    finally:
        stop(process)
    assert errors == []


def test_a_browser_leaving_the_player_mid_transfer_prints_no_traceback(capsys):
    from cartpole_warp.viz.web import PlayerServer

    with PlayerServer(("127.0.0.1", 0), None) as server:
        for gone in (BrokenPipeError, ConnectionResetError):
            try:
                raise gone
            except gone:
                server.handle_error(None, ("127.0.0.1", 1))
        assert capsys.readouterr().err == ""
        try:
            raise ValueError("a real fault")
        except ValueError:
            server.handle_error(None, ("127.0.0.1", 1))
        assert "ValueError: a real fault" in capsys.readouterr().err


@pytest.mark.parametrize("paused", [False, True])
def test_the_pages_pause_holds_training_until_a_stop_is_requested(make, paused):
    """TrainingView (train.py --viewer viser's ``on_iteration``) returns at once while the page's Pause is unchecked;
    checked, it holds the training loop, polling the page and the stop request (Ctrl-C), until the stop comes."""
    from cartpole_warp.evaluation.statistics import EpisodeSummary
    from cartpole_warp.viz.web import TrainingView

    polls = []

    def stopping():
        polls.append(True)
        return len(polls) >= 3

    view = TrainingView(make(num_envs=4), "127.0.0.1", free_port(), 4, stopping=stopping, paused=paused)
    try:
        view(0, EpisodeSummary(4, 1.0, 10.0, 0.1, 0.0))
    finally:
        view.close()
    assert len(polls) == (3 if paused else 0)


@pytest.mark.parametrize("interval_s", [0.0, 3600.0])
def test_training_draws_the_page_at_most_every_interval(make, interval_s):
    """Each update of the page makes the browser render (most of a core-second without a GPU, on the training's own
    cores): TrainingView draws an iteration only ``interval_s`` after the last drawn one."""
    from cartpole_warp.evaluation.statistics import EpisodeSummary
    from cartpole_warp.viz.web import TrainingView

    view = TrainingView(make(num_envs=4), "127.0.0.1", free_port(), 4, interval_s=interval_s)
    view.DRAW_RATIO = 0  # the interval alone decides
    drawn = []
    draw = view.viewer.draw
    view.viewer.draw = lambda *args: (drawn.append(args[0]), draw(*args))
    try:
        for iteration in range(3):
            view(iteration, EpisodeSummary(4, 1.0, 10.0, 0.1, 0.0))
    finally:
        view.close()
    assert drawn == ([0.0, 1.0, 2.0] if interval_s == 0 else [0.0])


@pytest.mark.parametrize("episode_length_s, play_metric, expected", [
    (10.0, "time_limit_fraction", "; 769 episodes ended, 768 of them at the time limit"),
    (None, "time_limit_fraction", "; 769 episodes ended"),
    (10.0, "full_reward_per_step", "; 769 episodes ended, mean reward per step of full-length episodes 0.100"),
])
def test_the_page_gives_the_tasks_play_metric_without_rounding_to_all(make, episode_length_s, play_metric, expected):
    """768 of 769 episodes at the time limit read as such (not '100%'); a task whose play metric is another mean (the
    swing-up's reward per step) shows that."""
    from cartpole_warp.evaluation.statistics import EpisodeStats
    from cartpole_warp.viz.web import WebViewer

    env = make(num_envs=4, task={"episode_length_s": episode_length_s})
    stats = EpisodeStats(env.device, env.max_episode_length)
    ended = torch.ones(769, dtype=torch.bool)
    stats.add(ended, torch.full((769,), 60.0), torch.full((769,), env.max_episode_length), torch.arange(769) > 0)
    viewer = WebViewer(env, "127.0.0.1", free_port(), 4, play_metric=play_metric)
    try:
        line = viewer.ended(stats.summary())
    finally:
        viewer.close()
    assert line == expected


def test_ctrl_c_interrupts_the_viewers_in_the_main_thread_and_leaves_other_threads_alone():
    import threading

    from cartpole_warp.viz.web import ctrl_c_interrupts

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)  # as a background job starts
    try:
        with ctrl_c_interrupts():
            assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN, "restored on the way out"
        errors = []

        def in_thread():
            try:
                with ctrl_c_interrupts():
                    pass
            except ValueError as err:  # signal.signal outside the main thread
                errors.append(err)

        thread = threading.Thread(target=in_thread)
        thread.start()
        thread.join()
        assert errors == []
    finally:
        signal.signal(signal.SIGINT, previous)
