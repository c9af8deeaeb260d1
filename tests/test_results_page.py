"""scripts/results.py, the generated results page's check (issue #28) and the README GIFs' provenance
(issue #32): run on a copy of the repository's records, it passes as committed and fails when a
policy file changes under its GIF, when a GIF is redrawn without recording it, or when a record's
interval is not its counts' Wilson interval."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def copy_tree(tmp: Path) -> Path:
    """The script, its records, the page, the GIF manifest and the files they name, under tmp."""
    for rel in ("scripts/results.py", "docs/results.md", "docs/figures/policy-gifs.json"):
        (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / rel, tmp / rel)
    shutil.copytree(ROOT / "docs/results", tmp / "docs/results")
    named = {g[k] for g in json.loads((ROOT / "docs/figures/policy-gifs.json").read_text())["gifs"]
             for k in ("gif", "policy")}
    for rec in (ROOT / "docs/results").glob("*.json"):
        p = json.loads(rec.read_text())["evaluated"].get("policy", "")
        if p and (ROOT / p).is_file() and not p.startswith("runs/"):
            named.add(p)
    for rel in named:
        (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / rel, tmp / rel)
    return tmp


def check(tree: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(tree / "scripts/results.py"), *args],
                          capture_output=True, text=True, timeout=60)


def test_the_committed_page_is_current(tmp_path):
    tree = copy_tree(tmp_path)
    r = check(tree, "--check")
    assert r.returncode == 0, r.stderr
    assert "up to date" in r.stdout


def test_a_changed_policy_file_makes_its_gif_stale(tmp_path):
    tree = copy_tree(tmp_path)
    policy = tree / "policies/grasp.dxpl"
    policy.write_bytes(policy.read_bytes() + b"\0")
    r = check(tree, "--check")
    assert r.returncode == 1
    assert "docs/figures/policy-grasp.gif shows another policies/grasp.dxpl" in r.stderr
    assert "python -m dexstack.render policies/grasp.dxpl" in r.stderr  # the command to redraw it


def test_a_redrawn_gif_is_recorded_by_gifs_drawn(tmp_path):
    tree = copy_tree(tmp_path)
    gif = tree / "docs/figures/policy-stack.gif"
    gif.write_bytes(gif.read_bytes()[:-1])
    r = check(tree, "--check")
    assert r.returncode == 1 and "is not the GIF" in r.stderr
    r = check(tree, "--gifs-drawn")
    assert r.returncode == 0, r.stderr
    assert check(tree, "--check").returncode == 0


def test_a_wrong_interval_fails(tmp_path):
    tree = copy_tree(tmp_path)
    rec = tree / "docs/results/table2-grasp-session14.json"
    data = json.loads(rec.read_text())
    data["interval_95"] = [90.0, 99.9]
    rec.write_text(json.dumps(data))
    r = check(tree, "--check")
    assert r.returncode == 1 and "is not the Wilson interval" in r.stderr
