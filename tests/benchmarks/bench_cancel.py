"""How fast every algorithm (and the shipped model) stops when canceled (issue 22).

Each algorithm runs on an input that keeps it busy for seconds (tests/cancel_runs.py); a
feedback cancels it after 0.5 s. The table gives the wall-clock and processor time from the
cancel to the end of the run (goal: under 1 s everywhere), and whether anything was written.
tests/test_cancel.py asserts the processor time; this prints both, with the load average.

Prints a table and writes tests/benchmarks/results/cancel.json.
Run: make bench  (or .venv/bin/python tests/benchmarks/bench_cancel.py)
"""
import json
import os
import platform
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
RESULTS = Path(__file__).resolve().parent / "results"

from bench_foundation import start_qgis  # noqa: E402


def main():
    app, provider, processing = start_qgis()
    import cancel_runs

    rows = {}
    delays = (cancel_runs.CANCEL_AFTER_S, 3.0)
    with tempfile.TemporaryDirectory() as tmp:
        inputs = cancel_runs.heavy_inputs(processing, Path(tmp) / "inputs")
        for alg_id in sorted(cancel_runs.RUNS):
            for after in delays:
                rows[f"{alg_id} @ {after:g} s"] = cancel_runs.cancel_run(
                    processing, alg_id, inputs, Path(tmp) / f"{alg_id}_{after}", after)
    print(f"{'algorithm @ cancel':40s} {'wall s':>8s} {'cpu s':>8s}  written  message")
    for key, r in rows.items():
        fmt = (lambda v: "finished" if v is None else f"{v:8.2f}")
        print(f"{key:40s} {fmt(r['wall_s']):>8s} {fmt(r['cpu_s']):>8s}  "
              f"{len(r['written']):7d}  {(r['message'] or '')[:40]}")
    worst = max((r["wall_s"] or 0) for r in rows.values())
    worst_cpu = max((r["cpu_s"] or 0) for r in rows.values())
    print(f"slowest stop: {worst:.2f} s wall, {worst_cpu:.2f} s processor (goal: under 1 s); "
          f"load average {os.getloadavg()[0]:.2f}")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "cancel.json").write_text(json.dumps({
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                    "load_average": os.getloadavg()},
        "cancel_after_s": delays, "runs": rows}, indent=1))


if __name__ == "__main__":
    main()
