"""Run every benchmark and print one table: `python -m bench.run [--json FILE] [NAME ...]`."""

from __future__ import annotations

import argparse
import importlib
import json
import sys

BENCHMARKS = {
    "link": "bench.link_throughput",
    "broad": "bench.broad",
    "stress": "bench.stress",
    "replay": "bench.replay",
    "ws_latency": "bench.ws_latency",
    "ws_fanout": "bench.ws_fanout",
    "soak": "bench.soak",
    "status": "bench.status",
    "replay_memory": "bench.replay_memory",
    "batch": "bench.batch",
    "estimators": "bench.estimators",
    "live_pipeline": "bench.live_pipeline",
    "serve_cpu": "bench.serve_cpu",
    "page_fps": "bench.page_fps",
    "wire": "bench.wire",
    "fleet_routing": "bench.fleet_routing",
    "loop_stalls": "bench.loop_stalls",
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("names", nargs="*", help=f"benchmarks to run (default all: {', '.join(BENCHMARKS)})")
    parser.add_argument("--json", help="also write the rows as JSON to this file")
    args = parser.parse_args(argv)
    rows: list[dict] = []
    for name in args.names or BENCHMARKS:
        print(f"running {name} ...", file=sys.stderr, flush=True)
        rows += importlib.import_module(BENCHMARKS[name]).main()
    columns = list(dict.fromkeys(k for row in rows for k in row))
    widths = {c: max(len(c), *(len(str(r.get(c, ""))) for r in rows)) for c in columns}
    print("  ".join(c.ljust(widths[c]) for c in columns))
    for r in rows:
        print("  ".join(str(r.get(c, "")).ljust(widths[c]) for c in columns))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
