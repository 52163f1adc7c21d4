"""Known vulnerabilities in what gcs runs on: pip-audit over this checkout's `.venv`, against
PyPI's advisory data (or OSV with `--service osv`), whenever the network allows.

    .venv/bin/pip install pip-audit && .venv/bin/python -m bench.audit [--service pypi|osv]

Prints one line per vulnerable package (name, version, advisory, fixed versions) and a summary.
Exit 0: every package audited, none vulnerable; 1: vulnerabilities found; 3: the advisory service
could not be reached or does not know the packages (a mirror without advisory data, no network),
so nothing, or not everything, was audited: never a silent pass. Not part of the test suite: its
answer changes with the advisory databases, not with the code. The floors in pyproject.toml say
which fixes gcs relies on (docs/security.md).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import sysconfig


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--service", choices=("pypi", "osv"), default="pypi", help="advisory service (default pypi)")
    args = parser.parse_args(argv)
    site = sysconfig.get_paths()["purelib"]
    command = [sys.executable, "-m", "pip_audit", "--path", site, "--skip-editable", "-f", "json", "-s", args.service]
    try:
        run = subprocess.run(command, capture_output=True, text=True, timeout=900)
    except FileNotFoundError:
        print("bench.audit: pip-audit is not installed: pip install pip-audit", file=sys.stderr)
        return 3
    try:
        report = json.loads(run.stdout)
    except ValueError:
        last = (run.stderr.strip().splitlines() or ["no output"])[-1]
        print(f"bench.audit: pip-audit failed: {last}", file=sys.stderr)
        return 3
    deps = report["dependencies"]
    skipped = [d for d in deps if "skip_reason" in d]
    vulnerable = [d for d in deps if d.get("vulns")]
    for dep in vulnerable:
        for vuln in dep["vulns"]:
            fixed = ", ".join(vuln.get("fix_versions", [])) or "no fix yet"
            print(f"{dep['name']} {dep['version']}: {vuln['id']} (fixed in {fixed})")
    audited = len(deps) - len(skipped)
    print(f"{audited} of {len(deps)} packages audited against {args.service}; {len(vulnerable)} vulnerable")
    if skipped:
        print(f"not audited ({len(skipped)}), e.g. {skipped[0]['skip_reason']}", file=sys.stderr)
    return 1 if vulnerable else 3 if skipped else 0


if __name__ == "__main__":
    sys.exit(main())
