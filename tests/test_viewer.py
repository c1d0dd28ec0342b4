"""play.py without --headless opens Newton's ViewerGL on a virtual display (Xvfb), runs and exits cleanly."""

import subprocess
import sys

from conftest import system_command


def test_play_opens_newtons_viewer_under_xvfb(repo, tmp_path):
    xvfb_run = system_command("xvfb-run", "apt-get install -y xvfb")
    result = subprocess.run([xvfb_run, "-a", "-s", "-screen 0 1280x800x24", sys.executable, str(repo / "play.py"),
                             "--agent", "zero", "--num-envs", "4", "--steps", "90", "--log-dir", str(tmp_path)],
                            cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "viewer closed after 90 env steps" in result.stdout, result.stdout + result.stderr
    assert "Traceback" not in result.stderr


def test_browser_viewer_without_the_extra_says_how_to_install_it(repo, tmp_path):
    """--viewer viser without viser installed (hidden here): one line naming the install command and a failing exit
    code (2: a usage error, in both)."""
    program = f"""
import contextlib, io, sys
sys.modules["viser"] = None
from cartpole_warp import play, train
for main, args in ((play.main, ["--agent", "zero", "--viewer", "viser"]),
                   (train.main, ["--num-envs", "64", "--viewer", "viser", "--log-dir", {str(tmp_path)!r}])):
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            code = main(args)
        except SystemExit as stop:
            code = stop.code
    print(code, repr(err.getvalue()))
"""
    result = subprocess.run([sys.executable, "-c", program], cwd=tmp_path, capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    said = [line.split(" ", 1) for line in result.stdout.splitlines() if line[:1].isdigit()]
    assert [int(code) for code, _ in said] == [2, 2], result.stdout
    for _, err in said:
        assert "pip install 'cartpole_warp[viser]'" in err and "Traceback" not in err, err
