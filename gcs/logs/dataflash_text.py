"""DataFlash text logs (.log): one record a line, "IMU, 81794643, -0.1165, ...", as an APM 2.5's
CLI log dump and Mission Planner's conversion write them, turned back into the binary records
the .bin reader reads (gcs.logs.dataflash), so both are decoded, checked and merged by one reader.

A line is a record's type name and its values, comma-separated; FMT lines ("FMT, 129, 31, PARM,
QNf, TimeUS,Name,Value") define the types as FMT records do. The scaled characters are written
as the values DFReader gives (c/C/e/E: value, L: degrees) and stored back as value·100 and
degrees·1e7. Only the types the reader wants are converted (the others are left as text). A line
that is no record of its FMT (too few or too many values, a value that is no number) is damage:
skipped and named by its line number, as is every place the binary reader finds.
"""

from __future__ import annotations

import bisect
import re
import struct
from collections.abc import Collection
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from gcs.logs.dataflash_format import FMT_DTYPE, FMT_TYPE, HEAD1, HEAD2
from gcs.logs.logfile import InputError

#: Format character → struct code (the binary layout of gcs.logs.dataflash_format.TYPES).
CODES = {
    "a": "32h", "b": "b", "B": "B", "g": "e", "h": "h", "H": "H", "i": "i", "I": "I", "f": "f", "d": "d",
    "n": "4s", "N": "16s", "Z": "64s", "c": "h", "C": "H", "e": "i", "E": "I", "L": "i", "M": "b", "q": "q",
    "Q": "Q",
}  # fmt: skip
#: Scaled characters → the factor the stored integer carries.
FACTORS = {"c": 100.0, "C": 100.0, "e": 100.0, "E": 100.0, "L": 1e7}
TEXT = "nNZ"
HEADER = bytes([HEAD1, HEAD2])


@dataclass
class TextFormat:
    type_id: int
    chars: str
    packer: struct.Struct


@dataclass
class TextImage:
    """The binary log, the line each of its records came from (by byte offset), and the lines
    that were no record: (line, cause)."""

    buf: npt.NDArray[np.uint8]
    starts: list[int] = field(default_factory=list)
    lines: list[int] = field(default_factory=list)
    damage: list[tuple[int, str]] = field(default_factory=list)

    def line_at(self, offset: int) -> int:
        """The line of the record at or before byte `offset` (the first line before any)."""
        k = bisect.bisect_right(self.starts, offset) - 1
        return self.lines[max(k, 0)] if self.lines else 1


def _value(char: str, text: str) -> object:
    if char in TEXT:
        return text.encode()
    if char in FACTORS:
        return round(float(text) * FACTORS[char])
    if char in "fdg":
        return float(text)
    try:
        return int(text)
    except ValueError:
        return int(float(text))  # "3.0" for an integer field


def _fmt_record(line: str, wanted: Collection[str], formats: dict[str, TextFormat]) -> bytes:
    """The binary FMT record of an FMT line (its type defined in `formats` when wanted);
    ValueError when it is none."""
    parts = [p.strip() for p in line.split(",", 5)[1:]]
    if len(parts) != 5:
        raise ValueError(f"FMT with {len(parts)} values, expected 5")
    type_id, name, chars, columns = int(parts[0]), parts[2], parts[3], parts[4].replace(" ", "")
    unknown = set(chars) - set(CODES)
    if unknown:
        raise ValueError(f"FMT of {name} with unknown format characters {''.join(sorted(unknown))!r}")
    packer = struct.Struct("<" + "".join(CODES[c] for c in chars))
    if name in wanted and name not in formats:
        formats[name] = TextFormat(type_id, chars, packer)
    row = (type_id, 3 + packer.size, name.encode(), chars.encode(), columns.encode())
    return HEADER + bytes([FMT_TYPE]) + np.array([row], dtype=FMT_DTYPE).tobytes()


def _record(name: str, line: str, fmt: TextFormat) -> bytes:
    """The binary record of a data line; ValueError when it is none of its FMT."""
    n = len(fmt.chars)
    values = [v.strip() for v in line.split(",", n if fmt.chars[-1] in TEXT else -1)[1:]]  # a text may hold commas
    if len(values) != n:
        raise ValueError(f"{name} with {len(values)} values, its FMT has {n}")
    try:
        return HEADER + bytes([fmt.type_id]) + fmt.packer.pack(*(_value(c, v) for c, v in zip(fmt.chars, values)))
    except (ValueError, OverflowError, struct.error) as exc:
        raise ValueError(f"{name}: a value is no number of its FMT ({exc})") from None


#: A record the CLI log dump of APM 2.x firmware printed before logs carried FMT lines, its name
#: followed by "," or ":" (ArduPlane and ArduCopter 2.x Log.pde, Log_Read_*): fixed layouts that
#: changed between releases, and no time in the RAW (gyro, accel) and ATT records.
FIXED_FORMAT_RECORD = re.compile(r"\s*(RAW|ATT|GPS|CTUN|NTUN|PM|CMD|CURR|MOD)\s*[,:]")


def _without_fmt(path: str, text: str) -> InputError:
    """Why a text with no FMT line is refused: records of firmware that wrote no FMT lines (the
    first named: no format to read them by, nor the IMU sample times an estimator needs, and no
    conversion can add what was never logged), else no DataFlash text log at all."""
    for number, line in enumerate(text.splitlines(), start=1):
        if found := FIXED_FORMAT_RECORD.match(line):
            return InputError(
                f"{path}: line {number}: {found[1]} record of a log with no FMT lines (APM 2.x firmware's fixed "
                "formats, IMU records without time; no conversion adds them): cannot be read, use the flight's .tlog"
            )
    return InputError(f"{path}: line 1: not a DataFlash text log (no FMT line such as 'FMT, 128, 89, FMT, ...')")


def text_image(path: str, wanted: Collection[str]) -> TextImage:
    """The binary image of the text log at path (the FMT lines and the records of `wanted` types);
    InputError when it cannot be read or has no FMT line."""
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            text = fh.read()
    except OSError as exc:
        raise InputError(f"{path}: line 1: cannot read ({exc.strerror})") from None
    formats: dict[str, TextFormat] = {}
    chunks: list[bytes] = []
    image = TextImage(np.zeros(0, dtype=np.uint8))
    size, fmt_lines = 0, 0
    for number, line in enumerate(text.splitlines(), start=1):
        name = line.partition(",")[0].strip()
        try:
            if name == "FMT":
                chunk = _fmt_record(line, wanted, formats)
                fmt_lines += 1
            elif name in formats:
                chunk = _record(name, line, formats[name])
            else:
                continue  # a type not read (or a blank line)
        except ValueError as exc:
            image.damage.append((number, f"{exc}; line skipped"))
            continue
        image.starts.append(size)
        image.lines.append(number)
        chunks.append(chunk)
        size += len(chunk)
    if not fmt_lines:
        raise _without_fmt(path, text)
    image.buf = np.frombuffer(b"".join(chunks), dtype=np.uint8)
    return image
