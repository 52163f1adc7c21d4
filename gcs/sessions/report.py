"""A self-contained HTML flight-test report of a session or any replayable log.

The source is replayed through every estimator (for a session this reproduces the live
numbers). The page holds: what was replayed (vehicle, duration, damage, what a log lacks), the attitude of every
source, each estimator's error against the best reference (truth if the log has it, else the
onboard estimate), an RMS / max table per estimator, reference and axis, a session's gain
changes, notes and events (its events.jsonl), and the message rates and packet loss. Every
source has the dashboard's colour (gcs.core.colors). Plots are PNG images (matplotlib, Agg)
embedded as data URIs, so the one file can be attached to a write-up.
"""

from __future__ import annotations

import base64
import html
import io
import json
import time
from pathlib import Path

import numpy as np

from gcs.core.colors import hex_color
from gcs.core.estimation import AttitudePoint
from gcs.core.protocol import METRIC_FIELDS, ProtocolTables, Series
from gcs.core.samples import REBOOT_CLOCK_JUMP
from gcs.mavlink.sampling import BOOT_SETTLE_S, UNREADY
from gcs.provenance import provenance
from gcs.sessions import layout
from gcs.sessions.contents import BootCounter, Contents, errors_by_boot, in_boot_order, read_events
from gcs.sessions.export import write_beside
from gcs.sessions.protocol import formatted, run_boot, session_tables
from gcs.sessions.sources import open_source

AXES = ("roll", "pitch", "yaw")
#: Reference used for the error plot, best first.
ERROR_REFERENCES = ("truth", "onboard", "ahrs2")
#: Line style per source, as the page draws them (truth dashed).
LINESTYLES = {"truth": "--"}
#: Event fields shown as their own columns (the rest goes to "detail").
EVENT_COLUMNS = ("wall_time", "host_time", "kind", "client")


def collect(source, progress=None, estimators: list[str] | None = None) -> tuple[dict[str, np.ndarray], object]:
    """Replay source through `estimators` (default every one); returns {source name: N×5 array t,
    roll, pitch, yaw, boot}, in replay order (boot: which boot of the vehicle, numbered over every
    source's points together, `BootCounter`) and the pipeline (for its comparisons)."""
    series: dict[str, list] = {}
    boots = BootCounter()

    def keep(points: list[AttitudePoint]) -> None:
        for p in points:
            series.setdefault(p.source, []).append((p.t, p.roll, p.pitch, p.yaw, boots.of(p.t)))

    pipeline = source.replay(source.new_pipeline(estimators), keep, progress)
    return {name: np.array(rows) for name, rows in series.items()}, pipeline


def png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def broken_at_wraps(t: np.ndarray, deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(t, deg) with a NaN between two samples more than 180° apart: an angle crossing ±180°
    (yaw, or roll upside down), where a line would otherwise cross the whole plot; and between the
    two boots of a vehicle that rebooted (its clock going back, REBOOT_CLOCK_JUMP), where a line
    would run back from the end of one boot to the start of the next. matplotlib breaks a line at
    a NaN, as the dashboard's plots break theirs."""
    jumps = np.flatnonzero((np.abs(np.diff(deg)) > 180.0) | (np.diff(t) < -REBOOT_CLOCK_JUMP)) + 1
    return np.insert(t, jumps, np.nan), np.insert(deg, jumps, np.nan)


def attitude_figure(series: dict[str, np.ndarray]):  # -> matplotlib Figure (imported lazily)
    from matplotlib.figure import Figure  # noqa: PLC0415 - ~0.5 s to import; only reports plot

    fig = Figure(figsize=(11, 7.5))
    axes = fig.subplots(3, 1, sharex=True)
    for name, data in sorted(series.items()):
        for k, ax in enumerate(axes):
            ax.plot(
                *broken_at_wraps(data[:, 0], np.degrees(data[:, 1 + k])),
                lw=0.8,
                label=name,
                color=hex_color(name),
                ls=LINESTYLES.get(name, "-"),
            )
    for k, ax in enumerate(axes):
        ax.set_ylabel(f"{AXES[k]} (deg)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8, ncol=4)
    axes[-1].set_xlabel("vehicle time (s)")
    return fig


def plot_errors(series: dict[str, np.ndarray], estimators: list[str], reference: str) -> str:
    from matplotlib.figure import Figure  # noqa: PLC0415 - ~0.5 s to import; only reports plot

    fig = Figure(figsize=(11, 7.5))
    axes = fig.subplots(3, 1, sharex=True)
    ref, ref_boots = in_boot_order(series[reference][:, :4], series[reference][:, 4].astype(np.int64))
    for name in estimators:
        if name not in series or len(series[name]) < 2:
            continue
        est, est_boots = in_boot_order(series[name][:, :4], series[name][:, 4].astype(np.int64))
        err, _ = errors_by_boot(est, est_boots, ref, ref_boots)  # each boot of the reference against the same boot
        for k, ax in enumerate(axes):
            ax.plot(*broken_at_wraps(err[:, 0], err[:, 1 + k]), lw=0.8, label=name, color=hex_color(name))
    for k, ax in enumerate(axes):
        ax.set_ylabel(f"{AXES[k]} error (deg)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title(f"estimator − {reference}")
    axes[-1].set_xlabel("vehicle time (s)")
    return png(fig)


def html_table(header: list[str], rows: list[list], name: str = "") -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>" for row in rows)
    attribute = f" class='{name}'" if name else ""
    return f"<table{attribute}><tr>{head}</tr>{body}</table>"


def plot_holds(tables: ProtocolTables, series: dict[str, Series]) -> str:
    """One panel per completed step: the step's axis of every source from the prompt to the end
    of the hold, the target, and the hold window shaded."""
    from matplotlib.figure import Figure  # noqa: PLC0415 - ~0.5 s to import; only reports plot

    windows = tables.windows
    cols = min(3, len(windows))
    rows = -(-len(windows) // cols)
    fig = Figure(figsize=(11, 2.8 * rows))
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
    for ax, window in zip(axes, windows):
        step = tables.protocol.steps[window.index]
        k = AXES.index(step.axis)
        for name, data in sorted(series.items()):
            part = data[(data[:, 0] >= window.t_start) & (data[:, 0] <= window.t_hold_end)]
            ax.plot(*broken_at_wraps(part[:, 0], np.degrees(part[:, 1 + k])), lw=0.8, label=name, color=hex_color(name))
        ax.axhline(step.target_deg, color="k", lw=0.6, ls="--")
        ax.axvspan(window.t_hold_start, window.t_hold_end, color="0.9")
        ax.set_title(f"{window.index + 1}. {step.name}", fontsize=9)
        ax.set_ylabel(f"{step.axis} (deg)", fontsize=8)
        ax.grid(alpha=0.3)
    for ax in axes[len(windows) :]:
        ax.set_visible(False)
    axes[0].legend(loc="best", fontsize=7, ncol=2)
    return png(fig)


#: The seed 000 step table's columns (SourceMetrics fields), as shown in the report.
STEP_COLUMNS = tuple(f for f in METRIC_FIELDS if f != "label")


def protocol_sections(tables: ProtocolTables, series: dict[str, Series]) -> list[str]:
    """Seed 000's tables (every source per step; per-axis means), seed 004's (MSE per axis,
    reduction relative to the raw accelerometer/magnetometer angles) and the holds' plots."""
    p = tables.protocol
    steps = [[formatted(getattr(m, f)) for f in STEP_COLUMNS] for m in tables.steps]
    means = [
        [m.source, m.axis, m.steps, formatted(m.mre_last_pct), formatted(m.mre_hold_pct)] for m in tables.axis_means
    ]
    mse = [
        [r.source, r.samples, *(formatted(v) for v in (r.mse_roll, r.mse_pitch, r.mse_yaw)),
         *(formatted(v) for v in (r.reduction_roll_pct, r.reduction_pitch_pct, r.reduction_yaw_pct))]
        for r in tables.mse
    ]  # fmt: skip
    intro = (
        f"<p>{html.escape(p.name)}: {html.escape(p.description)}. {len(tables.windows)} of {len(p.steps)} steps "
        f"completed. Every source against the target: mean relative error over the last {p.last_samples} samples "
        "(seed 000) and over the whole hold, %; absolute error, degrees; MSE per axis against the step's "
        "reference attitude, deg² (seed 004); rise (10–90 %) and settling time, s; cross-axis disturbance, "
        "degrees. accel_mag: the raw accelerometer/magnetometer angles. Definitions: docs/protocols.md.</p>"
    )
    return [
        f"<h2>Test protocol</h2>{intro}",
        "<h3>Seed 000: per step</h3>" + html_table(list(STEP_COLUMNS), steps, "protocol-steps"),
        "<h3>Seed 000: per axis (mean over the axis's steps)</h3>"
        + html_table(["source", "axis", "steps", "mre_last_pct", "mre_hold_pct"], means, "protocol-axis-means"),
        "<h3>Seed 004: MSE per axis over the holds and reduction relative to accel_mag</h3>"
        + html_table(
            ["source", "samples", "mse_roll", "mse_pitch", "mse_yaw"]
            + ["reduction_roll_pct", "reduction_pitch_pct", "reduction_yaw_pct"],
            mse,
            "protocol-mse",
        ),
        f"<h3>The holds</h3><img src='{plot_holds(tables, series)}'>",
    ]


def accuracy_rows(pipeline) -> list[list]:
    rows = []
    for name, comparison in pipeline.comparisons.items():
        summary = comparison.summary()
        for ref, stats in summary["references"].items():
            s = stats["session"]
            rows.append([name, ref, s["n"], *(f"{v:.2f}" for v in s["rms"]), *(f"{v:.2f}" for v in s["max"])])
    return rows


#: s: references further apart than this are told as two intervals
INTERVAL_GAP = 1.0


def unready_note(series: dict[str, np.ndarray]) -> str:
    """What the onboard figures leave out: ATTITUDE while the vehicle's EKF was not ready, or not
    yet known to be (at boot), scored as its own reference (gcs.mavlink.sampling.UNREADY); "" when there was none."""
    if UNREADY not in series:
        return ""
    t = series[UNREADY][:, 0]
    steps = np.diff(t)
    breaks = np.flatnonzero((steps > INTERVAL_GAP) | (steps < -REBOOT_CLOCK_JUMP))  # a reboot: its clock from 0
    starts, ends = t[np.r_[0, breaks + 1]], t[np.r_[breaks, len(t) - 1]]
    rebooted = np.r_[False, steps[breaks] < -REBOOT_CLOCK_JUMP]
    spans = ", ".join(
        f"{'after a reboot ' if r else ''}{a:.1f}–{b:.1f} s" for a, b, r in zip(starts, ends, rebooted, strict=True)
    )
    return (
        f"<p class='note'>{UNREADY}: the vehicle's ATTITUDE while its EKF_STATUS_REPORT said its EKF was not "
        f"initialised or its attitude not good, or in a boot's first {BOOT_SETTLE_S:.0f} s before its first report "
        f"({len(t)} references, vehicle time {spans}). It is scored apart: "
        "the onboard rows and the errors against onboard leave it out.</p>"
    )


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


def legend(names: list[str]) -> str:
    """The sources with their colours, as the dashboard shows them."""
    swatch = "<span class='source'><span class='swatch' style='background:{}'></span>{}</span>"
    return "<p class='legend'>" + " ".join(swatch.format(hex_color(n), html.escape(n)) for n in names) + "</p>"


def _number(value: object) -> str:
    """A gain value as typed: 6 significant digits, no float noise (0.0005, not 0.001)."""
    return f"{value:.6g}" if isinstance(value, int | float) and not isinstance(value, bool) else "–"


def _since(event: dict, start: float | None) -> str:
    t = event.get("wall_time")
    if not isinstance(t, int | float) or start is None:
        return "–"
    return f"{t - start:.1f}"


def event_sections(events: list[dict], start: float | None) -> list[str]:
    """A session's gain changes, notes and whole event log (times in s from the session start)."""
    gains = [
        [_since(e, start), e.get("estimator"), e.get("gain"), _number(e.get("old")), _number(e.get("new")),
         e.get("client")]
        for e in events
        if e.get("kind") == "gain"
    ]  # fmt: skip
    notes = [[_since(e, start), e.get("text"), e.get("client")] for e in events if e.get("kind") == "note"]
    rows = [
        [_since(e, start), e.get("kind"), e.get("client"),
         json.dumps({k: v for k, v in e.items() if k not in EVENT_COLUMNS}, default=str)]
        for e in events
    ]  # fmt: skip
    out = [
        "<h2>Gain changes</h2>"
        + (
            html_table(["t (s)", "estimator", "gain", "old", "new", "by"], gains, "gain-changes")
            if gains
            else "<p>none</p>"
        ),
        "<h2>Notes</h2>" + (html_table(["t (s)", "note", "by"], notes, "notes") if notes else "<p>none</p>"),
        "<h2>Events</h2>" + html_table(["t (s)", "kind", "by", "detail"], rows, "events"),
    ]
    return out


def render(
    source,
    series: dict[str, np.ndarray],
    pipeline,
    protocol: ProtocolTables | None = None,
    events: list[dict] | None = None,
    protocol_boot: int | None = None,
) -> str:

    estimators = list(pipeline.estimators)
    reference = next((r for r in ERROR_REFERENCES if r in series), None)
    meta = source.meta
    facts = [
        ["source", source.path],
        ["kind", source.kind],
        ["duration", f"{source.duration:.1f} s"],
        ["IMU samples", pipeline.imu_samples],
        ["damage", source.damage or "none"],
        *(["note", note] for note in source.notes),
    ]
    if meta:  # a session's, or a bare tlog's vehicle (named from its HEARTBEAT): what is known
        vehicle = meta.get("vehicle") or {}
        known = [
            ["vehicle", vehicle.get("label")],
            ["firmware", vehicle.get("firmware")],
            ["link", (meta.get("link") or {}).get("address")],
            ["recovered", meta.get("recovered")],
        ]
        facts += [row for row in known if row[1] is not None]
    sections = [f"<h2>Summary</h2>{html_table(['', ''], facts)}"]
    if series:
        figure = png(attitude_figure(series))
        sections.append(f"<h2>Attitude, every source</h2>{legend(sorted(series))}<img src='{figure}'>")
    if reference is not None:
        sections.append(f"<h2>Errors against {reference}</h2><img src='{plot_errors(series, estimators, reference)}'>")
    sections.append(
        "<h2>Accuracy (whole run, degrees)</h2>"
        + html_table(
            ["estimator", "reference", "n", "RMS roll", "RMS pitch", "RMS yaw", "max roll", "max pitch", "max yaw"],
            accuracy_rows(pipeline),
        )
        + unready_note(series)
    )
    for name, comparison in pipeline.comparisons.items():
        reliable, reason = comparison.reliability()
        if not reliable:
            sections.append(f"<p class='warn'>{html.escape(name)}: {html.escape(reason)}</p>")
    if events is not None:
        start = meta.get("start") if meta else None
        sections += event_sections(events, start if isinstance(start, int | float) else None)
    if protocol is not None:  # its windows are on the clock of the boot it ran in (protocol.run_boot)
        run = series if protocol_boot is None else {n: d[d[:, 4] == protocol_boot] for n, d in series.items()}
        sections += protocol_sections(protocol, run)
    sections.append("<h2>Rates</h2>" + html_table(["type", "count", "mean rate (Hz)"], traffic_rows(source)))
    if source.framing is not None:
        sections.append("<h2>Packets and loss</h2>" + html_table(["", ""], loss_rows(source)))
    return page(f"gcs report: {source.path}", sections)


def page(title: str, sections: list[str]) -> str:
    """The one self-contained HTML page style of gcs reports: title, provenance, sections."""
    deps = ", ".join(f"{name} {version}" for name, version in provenance().dependencies.items())
    return f"""<!doctype html><html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}table{{border-collapse:collapse;margin:8px 0}}
td,th{{border:1px solid #ccc;padding:2px 8px;text-align:right}}img{{max-width:100%}}.warn{{color:#a40}}
.source{{margin-right:1em}}.swatch{{display:inline-block;width:1em;height:.6em;margin-right:.3em}}</style>
</head><body><h1>{html.escape(title)}</h1>
<p>generated {time.strftime("%Y-%m-%d %H:%M:%S")} by {html.escape(str(provenance()))}; {html.escape(deps)}</p>
{"".join(sections)}</body></html>"""


def write_report(path: str, out: str, progress=None, estimators: list[str] | None = None) -> None:
    source = open_source(path)
    series, pipeline = collect(source, progress, estimators)
    tables, events, boot = None, None, None
    if layout.is_session(Path(path)):  # the recorded attitudes, as protocol.csv and the .mat have them
        contents = Contents(Path(path), "session", decode=lambda _: source)
        tables, boot = session_tables(contents), run_boot(contents)
        events = read_events(Path(path))
    text = layout.utf8_text(render(source, series, pipeline, tables, events, boot))
    write_beside(Path(out), lambda tmp: tmp.write_text(text, encoding="utf-8"))  # an earlier report stays if it fails
