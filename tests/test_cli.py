import os
import subprocess
import sys


def test_demo_fast_writes_summary(tmp_path):
    out = tmp_path / "demo"
    r = subprocess.run([sys.executable, "-m", "jaxsim", "demo", "--fast", "--out", str(out)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    text = (out / "summary.md").read_text()
    assert "| circle | fabrik | 150 |" in text and "Cloth" in text
    assert str(out) in r.stdout or os.path.abspath(str(out)) in r.stdout
    assert "[demo] IK 1/7" in r.stdout and "[demo] cloth" in r.stdout  # progress per scene
    from PIL import Image

    from jaxsim import curves

    stems = [f"ik_{c}" for c in curves.CURVES] + ["ik_circle_ccd", "cloth"]
    for stem in stems:
        png, gif = Image.open(out / f"{stem}.png"), Image.open(out / f"{stem}.gif")
        assert png.format == "PNG" and gif.format == "GIF" and gif.n_frames >= 7, stem
        assert f"{stem}.gif" in text
    assert Image.open(out / "cloth.gif").n_frames == 7  # 61 states, every 10th in --fast


def test_help_lists_commands():
    r = subprocess.run([sys.executable, "-m", "jaxsim", "--help"], capture_output=True, text=True, check=True)
    for cmd in ("demo", "report", "bench"):
        assert cmd in r.stdout
