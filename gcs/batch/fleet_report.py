"""`gcs fleet report`: one self-contained HTML page across the flights of a dataset.

Estimator error per flight (against each flight's best reference: truth, else onboard, else
AHRS2) and over time (flight start), the worst flights linked to their own `gcs report` page
(written beside the fleet page), the failures, and the latest sweep's result. Plots and page
come from gcs.sessions.report, so a fleet page looks like a flight's.
"""

from __future__ import annotations

import html
import math
import os
from collections import defaultdict
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from gcs.batch import dataset
from gcs.logs.logfile import InputError
from gcs.sessions import columnar
from gcs.sessions.export import write_beside
from gcs.sessions.report import ERROR_REFERENCES, html_table, page, png, write_report


def total_rms(row: dict) -> float:
    """sqrt(mean of the squared roll, pitch and yaw RMS), deg: the one number per flight."""
    return math.sqrt((row["rms_roll"] ** 2 + row["rms_pitch"] ** 2 + row["rms_yaw"] ** 2) / 3)


def scored_rows(summary: list[dict]) -> list[dict]:
    """Per flight and estimator, the row against the flight's best reference."""
    refs: dict[str, set[str]] = defaultdict(set)
    for row in summary:
        refs[row["flight"]].add(row["reference"])
    best = {f: next((r for r in ERROR_REFERENCES if r in have), None) for f, have in refs.items()}
    return [row for row in summary if row["reference"] == best[row["flight"]]]


def plot_per_flight(rows: list[dict], flights: list[str], estimators: list[str]) -> str:
    from matplotlib.figure import Figure  # noqa: PLC0415 - ~0.5 s to import; only reports plot

    fig = Figure(figsize=(11, 4 + 0.1 * len(flights)))
    ax = fig.subplots()
    width = 0.8 / max(1, len(estimators))
    by = {(r["flight"], r["estimator"]): total_rms(r) for r in rows}
    for k, est in enumerate(estimators):
        ax.barh(
            [i + k * width for i in range(len(flights))],
            [by.get((f, est), math.nan) for f in flights],
            height=width,
            label=est,
        )
    ax.set_yticks([i + 0.4 - width / 2 for i in range(len(flights))], flights, fontsize=7)
    ax.set_xlabel("total RMS error (deg) against the flight's best reference")
    ax.grid(alpha=0.3, axis="x")
    ax.legend(fontsize=8)
    return png(fig)


def plot_over_time(rows: list[dict], estimators: list[str]) -> str:
    from matplotlib.dates import date2num  # noqa: PLC0415 - ~0.5 s to import; only reports plot
    from matplotlib.figure import Figure  # noqa: PLC0415

    fig = Figure(figsize=(11, 4))
    ax = fig.subplots()
    for est in estimators:
        mine = sorted((r["started"], total_rms(r)) for r in rows if r["estimator"] == est)
        days = [date2num(datetime.fromtimestamp(t)) for t, _ in mine]
        ax.plot(days, [v for _, v in mine], "o", label=est)
    ax.xaxis_date()
    ax.set_ylabel("total RMS error (deg)")
    ax.set_xlabel("flight start")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return png(fig)


def _link_table(rows: list[tuple[str, str, list]]) -> str:
    """Worst flights: the name links to the flight's own report, or says why there is none (href
    "": the note is in the name)."""
    names = ("flight", "estimator", "reference", "total RMS", "RMS roll", "RMS pitch", "RMS yaw")
    head = "<tr>" + "".join(f"<th>{n}</th>" for n in names) + "</tr>"
    body = "".join(
        (
            f"<tr><td><a href='{html.escape(href)}'>{html.escape(name)}</a></td>"
            if href
            else f"<tr><td>{html.escape(name)}</td>"
        )
        + "".join(f"<td>{html.escape(str(c))}</td>" for c in cells)
        + "</tr>"
        for name, href, cells in rows
    )
    return f"<table>{head}{body}</table>"


def _flight_report(row: dict, out: Path, estimators: list[str]) -> str | None:
    """The flight's own `gcs report` page at `out`; None, or why not when its log cannot be read
    any more (moved, deleted or changed since the batch): the fleet page, made from the dataset
    alone, is still written (it failed whole, in one line, for one such flight)."""
    try:
        write_report(row["path"], str(out), estimators=estimators)
    except InputError as exc:
        return str(exc)
    return None


def latest_sweep(root: Path) -> Path | None:
    sweeps = sorted((root / dataset.SWEEPS).glob("*/preset.toml"), key=lambda p: p.stat().st_mtime)
    return sweeps[-1].parent if sweeps else None


def sweep_section(folder: Path) -> str:
    flights = columnar.read_parquet(folder / "flights.parquet").to_pylist()
    trials = columnar.read_parquet(folder / "trials.parquet").to_pylist()
    preset = (folder / "preset.toml").read_text()
    rows = [
        [f["path"], f["vehicle"], "holdout" if f["holdout"] else "train", f"{f['current']:.3f}", f"{f['best']:.3f}"]
        for f in flights
    ]
    return (
        f"<h2>Sweep {html.escape(folder.name)} ({len(trials)} trials)</h2><pre>{html.escape(preset)}</pre>"
        + html_table(["flight", "vehicle", "set", "current gains (deg)", "best gains (deg)"], rows)
    )


@dataclass(frozen=True)
class FleetPage:
    """What a fleet page holds: its flights, and those left out because a file of theirs could not
    be read (listed on the page, and for the command to name)."""

    flights: int
    skipped: list[dataset.Unreadable]


def write_fleet_report(path: str | os.PathLike, out: str | os.PathLike, worst: int = 3) -> FleetPage:
    """Write the page (and the worst flights' own reports into OUT_flights/). FileNotFoundError
    when the dataset has no flights."""
    root, target = Path(path), Path(out)
    summaries = dataset.read_summaries(root)
    summary = summaries.table.to_pylist()
    rows = scored_rows(summary)
    flights = sorted({r["flight"] for r in summary})
    estimators = sorted({r["estimator"] for r in summary})
    facts = {r["flight"]: r for r in summary}
    sections = [
        "<h2>Fleet</h2>"
        + html_table(
            ["flight", "kind", "vehicle", "firmware", "duration (s)", "IMU (Hz)", "damage"],
            [
                [
                    f,
                    facts[f]["kind"],
                    facts[f]["vehicle"],
                    facts[f]["firmware"],
                    f"{facts[f]['duration_s']:.1f}",
                    f"{facts[f]['imu_rate_hz']:.1f}",
                    facts[f]["damage"] or "",
                ]
                for f in flights
            ],
        )
    ]
    if rows:
        sections.append(f"<h2>Estimator error per flight</h2><img src='{plot_per_flight(rows, flights, estimators)}'>")
        sections.append(f"<h2>Estimator error over time</h2><img src='{plot_over_time(rows, estimators)}'>")
        worst_row = {r["flight"]: r for r in sorted(rows, key=total_rms)}  # each flight's worst estimator
        ranked = sorted(worst_row.values(), key=total_rms, reverse=True)[: max(0, worst)]
        pages = target.with_name(f"{target.stem}_flights")
        linked = []
        for r in ranked:
            pages.mkdir(exist_ok=True)
            unread = _flight_report(r, pages / f"{r['flight']}.html", estimators)
            linked.append(
                (
                    r["flight"] if unread is None else f"{r['flight']} (no report: {unread})",
                    f"{pages.name}/{r['flight']}.html" if unread is None else "",
                    [
                        r["estimator"],
                        r["reference"],
                        f"{total_rms(r):.2f}",
                        *(f"{r[f'rms_{a}']:.2f}" for a in ("roll", "pitch", "yaw")),
                    ],
                )
            )
        sections.append("<h2>Worst flights</h2>" + _link_table(linked))
    failures = dataset.read_failures(root)
    if failures.table.num_rows:
        failed = [[f["flight"], f["reason"]] for f in failures.table.to_pylist()]
        sections.append("<h2>Failures</h2>" + html_table(["flight", "reason"], failed))
    skipped = summaries.unreadable + failures.unreadable
    if skipped:
        left_out = [[s.flight, s.reason] for s in skipped]
        title = "<h2>Skipped: a file of theirs in the dataset cannot be read</h2>"
        sections.append(title + html_table(["flight", "reason"], left_out))
    sweep = latest_sweep(root)
    if sweep is not None:
        sections.append(sweep_section(sweep))
    text = page(f"gcs fleet report: {root}", sections)
    write_beside(target, lambda tmp: tmp.write_text(text))
    return FleetPage(len(flights), skipped)
