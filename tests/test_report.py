"""``python -m jaxsim report --quick`` into a temporary folder: tables, figures, key inequalities."""

import os
import re
import subprocess
import sys

import pytest

from PIL import Image

from _compile_flags import with_fast_compile

FIGURES = ["ik_humanoid.png", "ik_error_vs_iterations.png", "ik_error_vs_time.png", "ik_iterations_hist.png", "ik_jitter.png",
           "cloth_pareto.png", "cloth_stability_map.png", "cloth_cost_growth.png", "cloth_newton_log.png"]
SECTIONS = ["IK 1.", "IK 2.", "IK 3.", "IK 4.", "IK 5.", "Cloth 1.", "Cloth 2.", "Cloth 3.", "Cloth 4.", "Cloth 6."]


@pytest.mark.slow
def test_quick_report(tmp_path):
    """One test (one report run, whichever worker gets it): writes, then checks everything."""
    out = tmp_path / "report"
    r = subprocess.run([sys.executable, "-m", "jaxsim", "report", "--quick", "--out", str(out)],
                       capture_output=True, text=True, timeout=900, env=with_fast_compile(os.environ))
    assert r.returncode == 0, r.stderr[-3000:]
    report = out, (out / "report.md").read_text(), r.stdout
    check_tables_and_figures(report)
    check_fabrik_fewer_iterations_than_ccd_on_lab_circle(report)
    check_implicit_stable_where_explicit_is_not(report)
    check_bdf2_beside_backward_euler(report)
    check_humanoid_fabrik_ahead_of_ccd(report)
    # every file the run wrote is listed as its own: a second run may overwrite them
    from jaxsim._cli import _out

    _out.prepare(str(out), "report", force=False)


def tables_after(text, heading):
    """Markdown table rows (as lists of cells) in the section that starts at ``heading``."""
    start = text.index(heading)
    nxt = text.find("\n## ", start + 1)
    body = text[start: nxt if nxt > 0 else len(text)]
    rows = [ln for ln in body.splitlines() if ln.startswith("|") and not ln.startswith("|---")]
    return [[c.strip() for c in ln.strip("|").split("|")] for ln in rows]


def check_tables_and_figures(report):
    out, text, stdout = report
    for s in SECTIONS:
        rows = tables_after(text, "## " + s)
        assert len(rows) >= 3, s  # a header and at least two data rows
    for name in FIGURES:
        im = Image.open(out / name)
        assert im.format == "PNG" and min(im.size) > 100, name
        assert (out / name).stat().st_size < 200_000, name
        assert f"]({name})" in text
    assert "[report" in stdout and "cloth 2/4" in stdout  # progress lines


def check_fabrik_fewer_iterations_than_ccd_on_lab_circle(report):
    _, text, _ = report
    rows = tables_after(text, "### The lab's question")
    head, data = rows[0], rows[1:]
    mean = {(r[0], r[1]): float(r[head.index("mean sweeps/frame")]) for r in data}
    assert mean[("circle", "fabrik")] < mean[("circle", "ccd")]


def check_implicit_stable_where_explicit_is_not(report):
    _, text, _ = report
    # the per-cell classes are in the run's JSON-free markdown only as counts; re-derive from the map's cells table
    cells = re.findall(r"\| (lab cloth 11x11) \| (explicit[^|]*|implicit[^|]*) \| (\d+) \| (\d+) \| (\d+) \| (\d+) \|", text)
    counts = {c[1].strip(): (int(c[3]), int(c[5])) for c in cells}
    (_, ex_unstable), (_, im_unstable) = counts["explicit Euler (1 substep)"], counts["implicit Euler (Newton + line search)"]
    assert ex_unstable > 0 and im_unstable == 0
    assert "k = 1e4, dt = 1/30: explicit unstable, implicit stable" in text


def check_bdf2_beside_backward_euler(report):
    """BDF2 is in the Pareto table and the stability map: never unstable there, and with a
    fraction of backward Euler's physical error at the same CG tolerance."""
    _, text, _ = report
    cells = re.findall(r"\| lab cloth 11x11 \| BDF2 \(Newton \+ line search\) \| (\d+) \| (\d+) \| (\d+) \| (\d+) \|", text)
    assert len(cells) == 1 and int(cells[0][3]) == 0 and int(cells[0][0]) > 0, cells
    rows = tables_after(text, "## Cloth 1.")
    head, data = rows[0], rows[1:]
    col = next(i for i, h in enumerate(head) if h.startswith("physical error"))
    err = {r[1]: float(r[col]) for r in data if r[0] == "lab cloth 11x11" and r[col] != "unstable"}
    assert err["BDF2 CG tol 1e-06"] < 0.25 * err["implicit CG tol 1e-06"], err


def check_humanoid_fabrik_ahead_of_ccd(report):
    _, text, _ = report
    rows = {r[0]: r for r in tables_after(text, "## IK 5.")[1:]}
    assert float(rows["fabrik"][1]) >= 90.0 and float(rows["fabrik"][1]) > float(rows["ccd"][1]), rows
