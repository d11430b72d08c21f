import os
import subprocess
import sys

import pytest

from _compile_flags import with_fast_compile


@pytest.mark.slow
def test_demo_fast_writes_summary(tmp_path):
    out = tmp_path / "demo"
    r = subprocess.run([sys.executable, "-m", "jaxsim", "demo", "--fast", "--out", str(out)],
                       capture_output=True, text=True, timeout=600, env=with_fast_compile(os.environ))
    assert r.returncode == 0, r.stderr
    text = (out / "summary.md").read_text()
    assert "| circle | fabrik | 150 |" in text and "Cloth" in text
    assert str(out) in r.stdout or os.path.abspath(str(out)) in r.stdout
    assert "[demo] IK 1/7" in r.stdout and "[demo] cloth" in r.stdout  # progress per scene
    assert "[demo] section 5/8, cloth with colliders: done in" in r.stdout
    assert "[demo] section 6/8, the CMU walk: done in" in r.stdout
    assert "[demo] section 7/8, a cape on the CMU walk: done in" in r.stdout
    assert "[demo] section 8/8, a strip piling onto itself: done in" in r.stdout
    row = text.split("## Cloth self-contact")[1].splitlines()[4].split("|")
    assert row[2].strip() == "39" and row[8].strip() == "100%" and row[9].strip() == "0"  # converged, never crossed
    row = text.split("## Cloth on a character")[1].splitlines()[4].split("|")
    assert row[1].strip() == "100" and row[2].strip() == "45" and row[6].strip() == "100%"  # every step converged
    assert float(row[8]) > 0  # never inside the body
    row = text.split("## Animation: the CMU walk")[1].splitlines()[4].split("|")
    assert row[1].strip() == "240" and float(row[3]) < 0.01 < float(row[2])  # the toes slid, and do not after locking
    from PIL import Image

    walk = Image.open(out / "anim_walk.gif")
    assert walk.n_frames == 12 and min(walk.size) >= 480
    assert Image.open(out / "cape.gif").n_frames == 16  # 46 states, every 3rd
    assert Image.open(out / "cloth_pile.gif").n_frames == 11  # 31 states, every 3rd
    assert "(running" not in text  # the summary, written after every section, is complete
    from PIL import Image

    from jaxsim import curves

    stems = [f"ik_{c}" for c in curves.CURVES] + ["ik_circle_ccd", "cloth"]
    for stem in stems:
        png, gif = Image.open(out / f"{stem}.png"), Image.open(out / f"{stem}.gif")
        assert png.format == "PNG" and gif.format == "GIF" and gif.n_frames >= 7, stem
        assert f"{stem}.gif" in text
    assert Image.open(out / "cloth.gif").n_frames == 7  # 61 states, every 10th in --fast
    assert Image.open(out / "humanoid.gif").n_frames == 15 and "| 150 |" in text.split("humanoid")[1]
    row = text.split("## IK: the humanoid")[1].splitlines()[4]
    assert row.split("|")[4].strip() == "True", row  # every frame within tol, feet planted
    # every file the run wrote is listed as its own: a second run may overwrite them
    from jaxsim._cli import _out

    _out.prepare(str(out), "demo", force=False)


def test_help_lists_commands():
    r = subprocess.run([sys.executable, "-m", "jaxsim", "--help"], capture_output=True, text=True, check=True)
    for cmd in ("demo", "report", "bench"):
        assert cmd in r.stdout


def jaxsim_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "jaxsim", *args], capture_output=True, text=True, timeout=300, cwd=cwd)


def test_cli_refuses_to_overwrite_files_it_did_not_write(tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "summary.md").write_text("my notes")
    for cmd in ("demo", "report"):
        r = jaxsim_cli(cmd, "--fast" if cmd == "demo" else "--quick", "--out", str(out))
        assert r.returncode == 2 and "did not write" in r.stderr and "--force" in r.stderr
        assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
        assert "[demo]" not in r.stdout and "[report]" not in r.stdout  # refused before any work
    assert (out / "summary.md").read_text() == "my notes"


def test_cli_bad_out_is_one_line(tmp_path):
    f = tmp_path / "afile"
    f.write_text("x")
    for out, why in ((f, "is a file"), (f / "sub", "cannot create")):
        r = jaxsim_cli("demo", "--fast", "--out", str(out))
        assert r.returncode == 2 and why in r.stderr, r.stderr
        assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_out_manifest_rules(tmp_path):
    from jaxsim._cli import _out

    out = str(tmp_path / "o")
    before = _out.prepare(out, "demo", force=False)
    (tmp_path / "o" / "a.png").write_text("1")
    _out.record(out, "demo", before)
    _out.prepare(out, "demo", force=False)  # a re-run may overwrite its own files
    (tmp_path / "o" / "user.txt").write_text("2")
    with pytest.raises(_out.CLIError, match="user.txt"):
        _out.prepare(out, "demo", force=False)
    with pytest.raises(_out.CLIError, match="a.png"):
        _out.prepare(out, "report", force=False)  # another command's files are not its own
    before = _out.prepare(out, "demo", force=True)
    _out.record(out, "demo", before)
    with pytest.raises(_out.CLIError, match="user.txt"):  # --force does not adopt the user's file
        _out.prepare(out, "demo", force=False)


def test_bench_runs_only_the_package_benchmarks(tmp_path):
    fake = tmp_path / "benchmarks"
    fake.mkdir()
    marker = tmp_path / "ran"
    (fake / "_common.py").write_text("")
    (fake / "evil.py").write_text(f"open({str(marker)!r}, 'w').write('x')\n")
    r = jaxsim_cli("bench", "evil", cwd=str(tmp_path))
    assert r.returncode == 2 and "unknown benchmark" in r.stderr and not marker.exists()
    from jaxsim._cli.bench import bench_dir

    import jaxsim

    assert bench_dir() == os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(jaxsim.__file__))), "benchmarks")


def test_cli_enables_the_compilation_cache(tmp_path, monkeypatch):
    import jax

    from jaxsim._jobs.cache import enable_compilation_cache

    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "cache"))
    old = jax.config.jax_compilation_cache_dir
    try:
        assert enable_compilation_cache() == str(tmp_path / "cache")
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "cache")
    finally:
        jax.config.update("jax_compilation_cache_dir", old)


def test_no_cache_leaves_the_compilation_cache_off(tmp_path, monkeypatch):
    """``demo --no-cache`` sets ``JAXSIM_NO_CACHE`` before enabling anything: the cache stays off."""
    import jax

    from jaxsim import __main__ as cli
    from jaxsim._cli import demo
    from jaxsim._jobs.cache import enable_compilation_cache

    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("JAXSIM_NO_CACHE", raising=False)
    seen = []
    monkeypatch.setattr(demo, "run", lambda out, fast, checkpoint: seen.append(enable_compilation_cache()) or 0)
    old = jax.config.jax_compilation_cache_dir
    try:
        assert cli.main(["demo", "--no-cache", "--out", str(tmp_path / "demo")]) == 0
        assert seen == [None] and not (tmp_path / "cache").exists()
    finally:
        jax.config.update("jax_compilation_cache_dir", old)
        os.environ.pop("JAXSIM_NO_CACHE", None)


def test_help_and_bad_arguments_do_not_import_jax():
    code = ("import sys\nfrom jaxsim.__main__ import main\n"
            "for argv in (['--help'], ['demo', '--fastt']):\n"
            "    try:\n        main(argv)\n    except SystemExit:\n        pass\n"
            "assert 'jax' not in sys.modules, 'jax imported'\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "``" not in r.stdout  # no literal reST markup in --help


def test_bench_without_names_lists_and_runs_nothing():
    r = jaxsim_cli("bench")
    assert r.returncode == 0 and "ik_throughput" in r.stdout and "--all" in r.stdout
    assert "[bench]" not in r.stdout  # nothing started


def test_stages_print_heartbeats_with_the_last_runs_time(tmp_path, monkeypatch, capsys):
    """A long stretch prints a line every few seconds: elapsed, and the time left from the
    last run of the same stretch (kept beside the compilation cache)."""
    import time

    from jaxsim._jobs.progress import Stage

    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path))
    with Stage("[demo]", "a stage", every=0.05):
        time.sleep(0.3)
    first = capsys.readouterr().out.splitlines()
    assert first[0] == "[demo] a stage ..." and first[-1].startswith("[demo] a stage: done in")
    assert sum("no earlier run to estimate from" in line for line in first) >= 3
    with Stage("[demo]", "a stage", every=0.05):
        time.sleep(0.2)
    second = capsys.readouterr().out.splitlines()
    assert second[0].startswith("[demo] a stage ... (the last run took")
    assert any("s left (the last run took" in line for line in second[1:-1])
    with pytest.raises(RuntimeError), Stage("[demo]", "a failing stage", every=0.05):
        raise RuntimeError("boom")
    assert "done" not in capsys.readouterr().out  # no estimate saved for work that failed

