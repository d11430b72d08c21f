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


def test_help_lists_commands():
    r = subprocess.run([sys.executable, "-m", "jaxsim", "--help"], capture_output=True, text=True, check=True)
    for cmd in ("demo", "report", "bench"):
        assert cmd in r.stdout
