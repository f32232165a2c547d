"""Behaviour check for refactoring: run every shipped scene (a few frames each, every integrator
on hula, and a short render) and compare what it wrote with a recorded baseline.

    python scripts/check-behaviour.py record FILE     # before a change
    python scripts/check-behaviour.py check FILE      # after it: exit 1 on any difference

What is compared: each run's exit code, its whole stats.json except the wall-clock seconds
(which vary from run to run), and a SHA-256 of every PNG frame a render wrote. On the CPU the
simulation is bit-reproducible (forces are gathered, never scattered), so any difference is a
change of behaviour.
"""

import hashlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FRAMES = 12  # frames per scene run: enough for contact, retries and every kernel variant
INTEGRATORS = ("euler", "symplectic", "rk4", "implicit")


def runs() -> list[tuple[str, list[str]]]:
    """(label, command-line arguments) of every run the check makes."""
    scenes = sorted(ROOT.glob("scenes/*.toml")) + sorted(ROOT.glob("scenes/hard/*.toml"))
    listed = []
    for path in scenes:
        name = str(path.relative_to(ROOT))
        listed.append((name, ["simulate", name, "--frames", str(FRAMES)]))
    for integrator in INTEGRATORS:
        listed.append((f"hula/{integrator}", ["simulate", "hula", "--frames", "6", "--set",
                                              f"simulation.integrator={integrator}"]))
    listed.append(("render hula", ["render", "hula", "--frames", "3", "--width", "160",
                                   "--height", "120"]))
    listed.append(("render drape", ["render", "drape", "--frames", "2", "--width", "160",
                                    "--height", "120"]))
    return listed


def outcome(arguments: list[str]) -> dict:
    """Exit code, stats.json without wall seconds, and frame hashes of one run."""
    with tempfile.TemporaryDirectory() as folder:
        process = subprocess.run([sys.executable, "-m", "taichi_cloth", *arguments, "--out",
                                  folder, "--quiet"], cwd=ROOT, capture_output=True, text=True)
        result = {"exit": process.returncode}
        stats_path = Path(folder) / "stats.json"
        if stats_path.is_file():
            stats = json.loads(stats_path.read_text())
            stats.pop("wall_seconds", None)
            result["stats"] = stats
        result["frames"] = {path.name: hashlib.sha256(path.read_bytes()).hexdigest()
                            for path in sorted(Path(folder).glob("frames/*.png"))}
        if process.returncode not in (0, 3):
            result["stderr"] = process.stderr[-2000:]
    return result


def main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[0] not in ("record", "check"):
        print(__doc__)
        return 2
    mode, target = argv[0], Path(argv[1])
    results = {}
    for label, arguments in runs():
        results[label] = outcome(arguments)
        print(f"{label}: exit {results[label]['exit']}", flush=True)
    if mode == "record":
        target.write_text(json.dumps(results, indent=1, sort_keys=True))
        return 0
    baseline = json.loads(target.read_text())
    differing = [label for label in results if results[label] != baseline.get(label)]
    for label in differing:
        print(f"DIFFERS: {label}")
        for key in ("exit", "stats", "frames", "stderr"):
            if results[label].get(key) != baseline.get(label, {}).get(key):
                now, then = results[label].get(key), baseline.get(label, {}).get(key)
                if isinstance(now, dict) and isinstance(then, dict):
                    keys = sorted(k for k in set(now) | set(then) if now.get(k) != then.get(k))
                    print(f"  {key}: {keys[:12]}")
                else:
                    print(f"  {key}: {str(then)[:200]} -> {str(now)[:200]}")
    print(f"{len(results) - len(differing)} identical, {len(differing)} differ")
    return 1 if differing else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
