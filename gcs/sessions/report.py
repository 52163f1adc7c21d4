"""A self-contained HTML flight-test report of a session or any replayable log.

The source is replayed through every estimator (for a session this reproduces the live
numbers). The page holds: what was replayed (vehicle, duration, damage), the attitude of every
source, each estimator's error against the best reference (truth if the log has it, else the
onboard estimate), an RMS / max table per estimator, reference and axis, and the message rates
and packet loss. Plots are PNG images (matplotlib, Agg) embedded as data URIs, so the one file
can be attached to a write-up.
"""

from __future__ import annotations

import base64
import html
import io
import os
import time

import numpy as np

from gcs.core.comparison import errors_against
from gcs.core.estimation import AttitudePoint
from gcs.provenance import provenance
from gcs.sessions.sources import open_source

AXES = ("roll", "pitch", "yaw")
#: Reference used for the error plot, best first.
ERROR_REFERENCES = ("truth", "onboard", "ahrs2")


def collect(source, progress=None, estimators: list[str] | None = None) -> tuple[dict[str, np.ndarray], object]:
    """Replay source through `estimators` (default every one); returns {source name: N×4 array t,
    roll, pitch, yaw} and the pipeline (for its comparisons)."""
    series: dict[str, list] = {}

    def keep(points: list[AttitudePoint]) -> None:
        for p in points:
            series.setdefault(p.source, []).append((p.t, p.roll, p.pitch, p.yaw))

    pipeline = source.replay(source.new_pipeline(estimators), keep, progress)
    return {name: np.array(rows) for name, rows in series.items()}, pipeline


def png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def plot_attitude(series: dict[str, np.ndarray]) -> str:
    from matplotlib.figure import Figure  # noqa: PLC0415 - ~0.5 s to import; only reports plot

    fig = Figure(figsize=(11, 7.5))
    axes = fig.subplots(3, 1, sharex=True)
    for name, data in sorted(series.items()):
        for k, ax in enumerate(axes):
            ax.plot(data[:, 0], np.degrees(data[:, 1 + k]), lw=0.8, label=name)
    for k, ax in enumerate(axes):
        ax.set_ylabel(f"{AXES[k]} (deg)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8, ncol=4)
    axes[-1].set_xlabel("vehicle time (s)")
    return png(fig)


def plot_errors(series: dict[str, np.ndarray], estimators: list[str], reference: str) -> str:
    from matplotlib.figure import Figure  # noqa: PLC0415 - ~0.5 s to import; only reports plot

    fig = Figure(figsize=(11, 7.5))
    axes = fig.subplots(3, 1, sharex=True)
    ref = series[reference]
    for name in estimators:
        if name not in series or len(series[name]) < 2:
            continue
        err = errors_against(series[name], ref)
        for k, ax in enumerate(axes):
            ax.plot(err[:, 0], err[:, 1 + k], lw=0.8, label=name)
    for k, ax in enumerate(axes):
        ax.set_ylabel(f"{AXES[k]} error (deg)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title(f"estimator − {reference}")
    axes[-1].set_xlabel("vehicle time (s)")
    return png(fig)


def html_table(header: list[str], rows: list[list]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def accuracy_rows(pipeline) -> list[list]:
    rows = []
    for name, comparison in pipeline.comparisons.items():
        summary = comparison.summary()
        for ref, stats in summary["references"].items():
            s = stats["session"]
            rows.append([name, ref, s["n"], *(f"{v:.2f}" for v in s["rms"]), *(f"{v:.2f}" for v in s["max"])])
    return rows


def traffic_rows(source) -> list[list]:
    """Per message / record type: count and mean rate over the source's span."""
    span = (source.span[1] - source.span[0]) if source.span else 0.0
    return [
        [kind, n, f"{n / span:.1f}" if span > 0 else "-"]
        for kind, n in sorted(source.counts.items(), key=lambda kv: -kv[1])
    ]


def loss_rows(source) -> list[list]:
    f = source.framing
    if f is None:
        return []
    lost = sum(f.lost.values())
    return [
        ["packets", f.packets],
        ["CRC errors", f.crc_errors],
        ["bytes skipped", f.bytes_skipped],
        ["lost (by sequence number)", lost],
        ["loss", f"{100 * lost / max(lost + f.packets, 1):.2f} %"],
        *[[f"lost from sys {s} comp {c}", n] for (s, c), n in sorted(f.lost.items())],
    ]


def render(source, series: dict[str, np.ndarray], pipeline) -> str:

    estimators = list(pipeline.estimators)
    reference = next((r for r in ERROR_REFERENCES if r in series), None)
    meta = source.meta
    facts = [
        ["source", source.path],
        ["kind", source.kind],
        ["duration", f"{source.duration:.1f} s"],
        ["IMU samples", pipeline.imu_samples],
        ["damage", source.damage or "none"],
    ]
    if meta:
        vehicle = meta.get("vehicle") or {}
        facts += [
            ["vehicle", vehicle.get("label")],
            ["firmware", vehicle.get("firmware")],
            ["link", (meta.get("link") or {}).get("address")],
            ["recovered", meta.get("recovered")],
        ]
    sections = [f"<h2>Summary</h2>{html_table(['', ''], facts)}"]
    if series:
        sections.append(f"<h2>Attitude, every source</h2><img src='{plot_attitude(series)}'>")
    if reference is not None:
        sections.append(f"<h2>Errors against {reference}</h2><img src='{plot_errors(series, estimators, reference)}'>")
    sections.append(
        "<h2>Accuracy (whole run, degrees)</h2>"
        + html_table(
            ["estimator", "reference", "n", "RMS roll", "RMS pitch", "RMS yaw", "max roll", "max pitch", "max yaw"],
            accuracy_rows(pipeline),
        )
    )
    for name, comparison in pipeline.comparisons.items():
        reliable, reason = comparison.reliability()
        if not reliable:
            sections.append(f"<p class='warn'>{html.escape(name)}: {html.escape(reason)}</p>")
    sections.append("<h2>Rates</h2>" + html_table(["type", "count", "mean rate (Hz)"], traffic_rows(source)))
    if source.framing is not None:
        sections.append("<h2>Packets and loss</h2>" + html_table(["", ""], loss_rows(source)))
    return page(f"gcs report: {source.path}", sections)


def page(title: str, sections: list[str]) -> str:
    """The one self-contained HTML page style of gcs reports: title, provenance, sections."""
    deps = ", ".join(f"{name} {version}" for name, version in provenance().dependencies.items())
    return f"""<!doctype html><html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}table{{border-collapse:collapse;margin:8px 0}}
td,th{{border:1px solid #ccc;padding:2px 8px;text-align:right}}img{{max-width:100%}}.warn{{color:#a40}}</style>
</head><body><h1>{html.escape(title)}</h1>
<p>generated {time.strftime("%Y-%m-%d %H:%M:%S")} by {html.escape(str(provenance()))}; {html.escape(deps)}</p>
{"".join(sections)}</body></html>"""


def write_report(path: str, out: str, progress=None, estimators: list[str] | None = None) -> None:
    source = open_source(path)
    series, pipeline = collect(source, progress, estimators)
    text = render(source, series, pipeline)
    partial = f"{out}.partial"  # a failed write leaves any earlier report as it was
    try:
        with open(partial, "w") as fh:
            fh.write(text)
        os.replace(partial, out)
    finally:
        if os.path.exists(partial):
            os.remove(partial)
