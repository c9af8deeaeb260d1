#!/usr/bin/env python3
"""Writes docs/results.md, the one page of headline results, from the evaluation records in
docs/results/*.json (standard library only).

    python3 scripts/results.py           # (re)write docs/results.md
    python3 scripts/results.py --check   # exit 1 when docs/results.md differs from what the records give
    python3 scripts/results.py --gifs-drawn  # after redrawing the README's GIFs: record their hashes

A record comes from `trainer eval POLICY --record docs/results/NAME.json --section KEY --what LABEL`
(fields below; add `order`, `paper`, `session` or `history` by hand where wanted).

A record is one evaluation: what was evaluated (a policy file, with its sha256 when the file is in
the repository), the command that produced the figure, successes, episodes, the 95% interval, the
start seed, date, machine and compute. Both modes also check every record: required fields, the
interval against the Wilson interval of successes / episodes, and the sha256 of a policy file in the
repository (a replaced file needs a new evaluation and a new record; the old record stays, marked
`history`). A figure that changes gets a
new record; the old one stays with a `history` field saying why it is no longer current.
"""

import argparse
import hashlib
import json
import math
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RECORDS = ROOT / "docs" / "results"
PAGE = ROOT / "docs" / "results.md"
# The README's GIFs of the shipped policies: which file each shows, and the command that drew it.
GIFS = ROOT / "docs" / "figures" / "policy-gifs.json"

REQUIRED = {
    "section": str,
    "order": int,
    "what": str,
    "evaluated": dict,
    "command": str,
    "successes": int,
    "episodes": int,
    "interval_95": list,
    "start_seed": int,
    "evaluation": str,
    "date": str,
    "machine": str,
    "compute": str,
    "source": str,
}

# Sections of the page, in order: (key, title, text above the table).
SECTIONS = [
    (
        "table2",
        "Table II: the shipped policies over 1000 starts",
        "The paper's Table II: success of the best Grasp, StackInHand and Stack policies over 1000 "
        "random starts (seeds from 3,000,000, apart from training, selection and final evaluations). "
        "Ours are the files in `policies/` (clones by the imitation learner, the StackInHand clone then "
        "fine-tuned by the RL learner, the Grasp file distilled from the mean of eight clones, the Stack file one clone that also learnt from demonstrations started with the bricks close together; how each was made: "
        "[policies/README.md](../policies/README.md)). `bash experiments/table2.sh` runs the three "
        "evaluations. The first row of each task is the latest evaluation on the current code; rows "
        "marked *history* are earlier evaluations, of the same file (same sha256) or of the file it "
        "replaced (its note says which).",
    ),
    (
        "main-job",
        "The main job: `bash scripts/main.sh`",
        "README command one: learn Grasp with the imitation learner (`trainer imitate`, its defaults, "
        "seed 0), export the policy file and evaluate it through the controller's runtime on 200 "
        "unseen starts.",
    ),
    (
        "ddpg-demos",
        "DDPG from demonstrations on Grasp: `trainer train --task grasp --preset demos`",
        "The default of `trainer train` for the manipulation tasks until session 16, which made the "
        "clone stage and its guarded fine-tune (`--preset finetune`) the default (`--preset demos`: "
        "200 recorded demonstrations, 20,000 pre-training updates, 20,000 transitions; the "
        "ablation's `no-norm` row, [experiments.md](experiments.md#ablation-at-grasp-scale-issue-12)). "
        "Its later seed-0 figure over 100 starts is in the side by side below.",
    ),
    (
        "side-by-side",
        "Side by side with Stable-Baselines3",
        "Seed 0 per learner, one thread each, the same dexstack environment, reward and starts "
        "(protocol, curves and reading: [benchmarks.md](benchmarks.md#side-by-side-with-stable-baselines3-sessions-8-10-issue-14)). "
        "Reach at the issue's 60,000 transitions (session 9), Grasp at 200,000 (session 10); "
        "final success over 100 starts from 1,000,000. CPU times of sessions 9 and 10 come from "
        "different CPUs. SB3's rows are its actors run in Python, except the row marked "
        "\"through the runtime\" (session 15): an SB3 actor exported to ONNX, imported as a policy "
        "file and run by `trainer eval` like ours.",
    ),
]


def wilson(successes, episodes, z=1.959963984540054):
    """95% Wilson score interval in percent, as `env/src/evaluate.rs` computes it."""
    p = successes / episodes
    d = 1 + z * z / episodes
    c = (p + z * z / (2 * episodes)) / d
    h = z * math.sqrt(p * (1 - p) / episodes + z * z / (4 * episodes * episodes)) / d
    return 100 * (c - h), 100 * (c + h)


def load():
    """Reads and checks every record; returns (records, errors)."""
    records, errors = [], []
    files = sorted(RECORDS.glob("*.json"))
    if not files:
        errors.append(f"no records in {RECORDS.relative_to(ROOT)}/")
    keys = {s[0] for s in SECTIONS}
    for f in files:
        name = f.relative_to(ROOT)
        try:
            r = json.loads(f.read_text(encoding="utf-8"))
        except (OSError, ValueError) as e:
            errors.append(f"{name}: cannot read: {e}")
            continue
        bad = [k for k, t in REQUIRED.items() if not isinstance(r.get(k), t)]
        if bad:
            errors.append(f"{name}: missing or mistyped field(s): {', '.join(bad)}")
            continue
        if r["section"] not in keys:
            errors.append(f"{name}: unknown section {r['section']!r} (one of {sorted(keys)})")
        if not 0 <= r["successes"] <= r["episodes"] or r["episodes"] == 0:
            errors.append(f"{name}: successes {r['successes']} of {r['episodes']} episodes")
            continue
        lo, hi = wilson(r["successes"], r["episodes"])
        ci = r["interval_95"]
        numbers = len(ci) == 2 and all(isinstance(x, (int, float)) for x in ci)
        if not numbers or abs(ci[0] - lo) > 0.051 or abs(ci[1] - hi) > 0.051:
            errors.append(
                f"{name}: interval_95 {ci} is not the Wilson interval of "
                f"{r['successes']}/{r['episodes']} ({lo:.1f}-{hi:.1f})"
            )
        policy = r["evaluated"].get("policy", "")
        digest = r["evaluated"].get("sha256")
        if digest is not None:
            path = ROOT / policy
            if not path.is_file():
                if not r.get("history"):
                    errors.append(f"{name}: {policy} has a sha256 but is not in the repository")
            elif hashlib.sha256(path.read_bytes()).hexdigest() != digest and not r.get("history"):
                # A history record may describe a file since replaced; a current one may not.
                errors.append(
                    f"{name}: {policy} is not the file this record evaluated (sha256 differs): "
                    "evaluate the new file, add its record and mark this one `history`"
                )
        r["_file"] = str(name)
        records.append(r)
    return records, errors


def sha256(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def load_gifs(refresh=False):
    """Reads the GIF manifest and checks each GIF and the policy file it shows against the
    sha256s recorded when it was drawn; with `refresh`, records the current ones instead.
    Returns (entries, errors)."""
    name = GIFS.relative_to(ROOT)
    try:
        manifest = json.loads(GIFS.read_text(encoding="utf-8"))
        entries = manifest["gifs"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        return [], [f"{name}: cannot read: {e}"]
    errors = []
    for g in entries:
        if not all(isinstance(g.get(k), str) for k in ("gif", "policy", "command", "shows")):
            errors.append(f"{name}: an entry lacks gif, policy, command or shows: {g}")
            continue
        gif, policy = ROOT / g["gif"], ROOT / g["policy"]
        missing = [p for p in (gif, policy) if not p.is_file()]
        if missing:
            errors.append(f"{name}: {', '.join(str(p.relative_to(ROOT)) for p in missing)} not in the repository")
            continue
        if refresh:
            g["gif_sha256"], g["policy_sha256"] = sha256(gif), sha256(policy)
            continue
        if g.get("policy_sha256") != sha256(policy):
            errors.append(
                f"{g['gif']} shows another {g['policy']} than the one in the repository: redraw it with "
                f"`{g['command']}`, then run `python3 scripts/results.py --gifs-drawn`"
            )
        elif g.get("gif_sha256") != sha256(gif):
            errors.append(
                f"{g['gif']} is not the GIF {name} lists: if it was redrawn with its command, "
                "run `python3 scripts/results.py --gifs-drawn`"
            )
    if refresh and not errors:
        GIFS.write_text(json.dumps(manifest, indent=2) + "\n", encoding="utf-8")
    return entries, errors


def cell(text):
    return str(text).replace("|", "\\|").replace("\n", " ")


def render(records, gifs):
    out = [
        "# Results: the headline figures",
        "",
        "<!-- Generated by `python3 scripts/results.py` from docs/results/*.json: do not edit by hand.",
        "     Change or add a record, then run the script; `scripts/test.sh` fails when this page is stale. -->",
        "",
        "Every figure below is one evaluation record in [`docs/results/`](results/) with the command "
        "that produced it, its date and machine. `trainer eval POLICY --record docs/results/NAME.json "
        "--section KEY --what LABEL` writes a record (the file's sha256, the command, the counts, the "
        "interval, the date, the machine, the wall time); records of evaluations made before that "
        "flag existed were written from the figures the docs reported with their commands. "
        "Generated by `python3 scripts/results.py`; "
        "`python3 scripts/results.py --check` (run by `scripts/test.sh`) fails when this page differs "
        "from the records, when an interval is not the Wilson interval of its counts, or when a "
        "policy file in the repository no longer matches the sha256 its record evaluated. Every "
        "other measured figure, with its command: [benchmarks.md](benchmarks.md), "
        "[experiments.md](experiments.md).",
        "",
        "Success counts the task's predicate at the last step of each episode; intervals are 95% "
        "Wilson intervals.",
    ]
    for key, title, text in SECTIONS:
        rows = sorted((r for r in records if r["section"] == key), key=lambda r: (r["order"], r["_file"]))
        if not rows:
            continue
        paper = any("paper" in r for r in rows)
        transitions = any("transitions" in r for r in rows)
        head = ["what", "evaluated"]
        if transitions:
            head.append("transitions")
        head += ["success (95% CI)", "starts"]
        if paper:
            head.append("paper")
        head += ["command", "date, machine", "compute", "record"]
        out += ["", f"## {title}", "", text, "", "| " + " | ".join(head) + " |",
                "|" + "|".join("---" for _ in head) + "|"]
        for r in rows:
            what = r["what"]
            if r.get("history"):
                what = f"*history*: {what}"
            ev = f"`{r['evaluated'].get('policy', '')}`"
            if r["evaluated"].get("sha256"):
                ev += f" (sha256 `{r['evaluated']['sha256'][:12]}`)"
            rate = 100 * r["successes"] / r["episodes"]
            lo, hi = r["interval_95"]
            succ = f"{r['successes']}/{r['episodes']} = {rate:.1f}% ({lo:.1f}-{hi:.1f})"
            if not r.get("history"):
                succ = f"**{succ}**"
            starts = f"{r['episodes']} from {r['start_seed']:,}"
            when = r["date"]
            if "session" in r:
                when += f", session {r['session']}"
            if "commit" in r:
                when += f", commit {r['commit']}"
            when += f"; {r['machine']}"
            row = [what, ev]
            if transitions:
                row.append(f"{r['transitions']:,}" if "transitions" in r else "")
            row += [succ, starts]
            if paper:
                row.append(r.get("paper", ""))
            row += [f"`{r['command']}`", when, r["compute"], f"[{Path(r['_file']).name}](results/{Path(r['_file']).name})"]
            out.append("| " + " | ".join(cell(c) for c in row) + " |")
        notes = [r for r in rows if r.get("history") or r.get("note")]
        if notes:
            out.append("")
            for r in notes:
                parts = [p for p in (r.get("note"), r.get("history") and f"history: {r['history']}") if p]
                out.append(f"- {r['what']} ({r['date']}): {'; '.join(parts)}.")
        out.append("")
        out.append("How each figure was measured: " + "; ".join(
            sorted({r["evaluation"] for r in rows})) + ". Where it was first reported: " + "; ".join(
            sorted({r["source"] for r in rows})) + ".")
    if gifs:
        out += ["", "## The README's GIFs", "",
                "Which policy file each GIF of the README shows (the file's sha256 when the GIF was "
                "drawn; the check above fails when either changes) and the command that drew it.", "",
                "| GIF | shows | policy file | command |", "|---|---|---|---|"]
        for g in gifs:
            out.append("| " + " | ".join(cell(c) for c in (
                f"[{Path(g['gif']).name}]({os.path.relpath(ROOT / g['gif'], PAGE.parent)})", g["shows"],
                f"`{g['policy']}` (sha256 `{g['policy_sha256'][:12]}`)", f"`{g['command']}`")) + " |")
    return "\n".join(out) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true",
                    help="do not write; exit 1 when docs/results.md is stale or a record is wrong")
    ap.add_argument("--gifs-drawn", action="store_true",
                    help=f"record the current sha256s of the GIFs in {GIFS.relative_to(ROOT)} and their policy files")
    args = ap.parse_args()
    if args.gifs_drawn:
        _, errors = load_gifs(refresh=True)
        for e in errors:
            print(f"error: {e}", file=sys.stderr)
        if errors:
            sys.exit(1)
        print(f"recorded the GIFs' and policy files' sha256 in {GIFS.relative_to(ROOT)}")
    records, errors = load()
    gifs, gif_errors = load_gifs()
    errors += gif_errors
    if errors:
        for e in errors:
            print(f"error: {e}", file=sys.stderr)
        sys.exit(1)
    page = render(records, gifs)
    if args.check:
        current = PAGE.read_text(encoding="utf-8") if PAGE.exists() else None
        if current != page:
            what = "is missing" if current is None else "differs from what docs/results/*.json give"
            print(f"error: docs/results.md {what}: run `python3 scripts/results.py` and commit the page "
                  "(never edit it by hand)", file=sys.stderr)
            sys.exit(1)
        print(f"docs/results.md is up to date with {len(records)} records")
        return
    PAGE.write_text(page, encoding="utf-8")
    print(f"wrote docs/results.md from {len(records)} records")


if __name__ == "__main__":
    main()
