"""play.py without --headless opens Newton's ViewerGL on a virtual display (Xvfb), runs and exits cleanly."""

import shutil
import subprocess
import sys


def test_play_opens_newtons_viewer_under_xvfb(repo, tmp_path):
    xvfb_run = shutil.which("xvfb-run")
    assert xvfb_run, "the viewer test needs Xvfb: apt-get install -y xvfb (.ci/run installs it)"
    result = subprocess.run([xvfb_run, "-a", "-s", "-screen 0 1280x800x24", sys.executable, str(repo / "play.py"),
                             "--agent", "zero", "--num-envs", "4", "--steps", "90", "--log-dir", str(tmp_path)],
                            cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "viewer closed after 90 env steps" in result.stdout, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
