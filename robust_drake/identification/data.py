"""Measured data for identification: canonical CSV, DFKI adapter, validation, filtering.

Canonical CSV (what :func:`write_canonical_csv` writes and every command reads)
    columns ``t, q1..qn, tau1..taun``, optional ``qd1..qdn, qdd1..qddn``; SI units
    (s, rad, rad/s, rad/s^2, N m).

DFKI adapter (the DFKI RIC double-pendulum records, ``../shared/data/dfki_double_pendulum``)
    columns ``time, pos_meas*, vel_meas*, tau_con*, tau_meas*``; the torque column is chosen
    with ``torque="tau_meas"`` (default: the driver's current-based estimate) or ``"tau_con"``
    (the command). ``vel_meas*`` is a plain finite difference there, so it is *not* used.

Velocity / acceleration convention (one convention, applied everywhere)
    0. conditioning (:mod:`robust_drake.identification.conditioning`): every file is split at
       logging gaps (a step > ``GAP_FACTOR`` x the median) into segments, and every segment is
       put on a uniform grid: stamps that scatter around a fixed rate are replaced by the fitted
       grid (samples kept), truly irregular sampling is resampled by a cubic spline (a
       DataWarning says which); segments too short for the filters are dropped (warning);
    1. positions and torques are low-pass filtered with the *same* zero-phase Butterworth
       filter (order ``FilterSettings.order`` run forwards and backwards with
       ``scipy.signal.filtfilt``, so no phase lag and an effective order 2*order; cut-off
       ``cutoff_hz``, default 8 Hz);
    2. ``qd`` = central difference (``numpy.gradient`` with the segment's uniform period, never
       over logged stamps) of the filtered positions (or, with ``velocities="logged"``, the
       low-passed logged velocity); ``qdd`` = central difference of ``qd``;
    3. filtering both sides of tau = Y(q, qd, qdd) theta identically keeps the linear model
       consistent (the filter commutes with the linear map up to the nonlinearity of Y, which
       is small below the cut-off);
    4. the first and last ``2 / cutoff_hz`` seconds of every segment are cut after filtering
       (start-up transients of the filter and of torque steps at t = 0; ``trim_s`` overrides);
       the rule is recorded in ``FilterSettings.trim_s`` and a second load of the same files at
       another cut-off (instruments) reuses it (:func:`load_companion`: same rows, checked);
    5. stiction: rows where a joint sticks are marked in ``IdentData.stuck`` (warning above 10 %).
    Velocities given in a canonical CSV (``qd*``, ``qdd*``) are used as given when
    ``use_given_derivatives=True``; otherwise they are recomputed by the convention above.

Validation never silently drops anything: missing/duplicate columns (read from the raw header
line: pandas would rename a second copy and ignore it), non-increasing time, time that looks like milliseconds (median step > ``MAX_SAMPLE_PERIOD_S``),
NaN/inf or absurd values (|x| > ``MAX_ABS_VALUE``; column and row named), wrong joint count,
constant or too-short signals and positions that look like degrees all raise
:class:`DataError` with the file name and what to do. Warnings (``IdentData.warnings``, each a one-line
:class:`DataWarning`): gaps, stamp jitter, resampling, dropped segments, stiction, derivatives
inconsistent with the motion, unpowered joints, logged velocities that disagree with the derivative of the positions
(units); ``IdentData.position_counts`` records each joint's range in encoder counts
(:func:`frozen_joints`: at most ``FROZEN_MAX_COUNTS`` counts = unidentifiable joint).
Checks that need the robot model (units against the URDF, sample budget, files used twice,
URDF masses) are in :mod:`robust_drake.identification.input_checks`.
"""

from __future__ import annotations

import dataclasses
import math
import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from robust_drake.errors import DataError
from robust_drake.identification.input_checks import n_effective  # noqa: F401 - its home before

DEFAULT_CUTOFF_HZ = 8.0
DEFAULT_FILTER_ORDER = 4
MIN_SAMPLES = 50
#: peak |q| above which positions "look like degrees" (4 pi rad = two full turns)
DEGREE_THRESHOLD_RAD = 4.0 * np.pi
#: |value| above which a position/velocity/acceleration/torque entry is refused as absurd (SI)
MAX_ABS_VALUE = 1e6
#: median sampling period above which the time column "looks like milliseconds" [s] (10 Hz:
#: slower than any identification log; a 500 Hz log in ms steps by 2.0)
MAX_SAMPLE_PERIOD_S = 0.1
#: logged velocity vs derivative of the logged position: slope outside [1/x, x] -> warning
VELOCITY_SLOPE_TOL = 3.0
#: a joint whose position range spans at most this many encoder counts is unidentifiable
FROZEN_MAX_COUNTS = 2


class DataWarning(UserWarning):
    """Data usable but suspicious (poor excitation, unpowered joint, large jitter)."""


@dataclass
class FilterSettings:
    """The differentiation/filter convention actually applied (recorded in reports)."""

    cutoff_hz: float | None = DEFAULT_CUTOFF_HZ  # None = no filtering
    order: int = DEFAULT_FILTER_ORDER
    method: str = "zero-phase Butterworth (filtfilt) on q and tau, central differences for qd, qdd"
    derivatives: str = "computed"  # or "given" (from qd*/qdd* columns)
    #: samples cut at *each* end of every file after filtering (filter start-up transients;
    #: default = 2 / cutoff seconds); reported, never silent
    trim_samples: int = 0
    #: the trim rule in seconds (one value for every segment and for every load of the same
    #: files, e.g. the instrument load: :func:`load_companion`); samples = round(trim_s / T_segment)
    trim_s: float = 0.0
    #: where the derivatives come from: "positions" (differentiated twice) or "logged velocities"
    velocities: str = "positions"

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class RawData:
    """One file as read (before filtering): time, positions, torques, optional derivatives."""

    t: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    qd: np.ndarray | None = None
    qdd: np.ndarray | None = None
    source: str = "<memory>"
    fmt: str = "canonical"  # or "dfki"
    torque_column: str = "tau"
    #: the file's column names behind each array ({"q": ["q1", "q2"], ...}; for messages)
    columns: dict = field(default_factory=dict)
    #: (N,) the file line of each row (comments and blank lines skipped; None = row + 2)
    lines: np.ndarray | None = None
    #: what the reader skipped or suspects (comment lines, a cut last line): warnings
    notes: list = field(default_factory=list)

    def line(self, row: int) -> int:
        """The file line of data row ``row`` (0-based)."""
        return int(self.lines[row]) if self.lines is not None and row < len(self.lines) else row + 2

    @property
    def n(self) -> int:
        return self.q.shape[1]


@dataclass
class IdentData:
    """Samples ready for identification (SI units); arrays are (N, n).

    ``segment`` (N,) labels the gap-free stretch of a file each sample came from (filtering,
    differentiation and trimming never cross a segment boundary; replays reset at segment
    starts; ``conditioning`` holds one dict per segment with its source). ``sources`` lists the files.
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    dt: float
    robot: str | None = None
    sources: list[str] = field(default_factory=list)
    filter: FilterSettings = field(default_factory=FilterSettings)
    segment: np.ndarray | None = None
    jitter: float = 0.0  # std(dt) / mean(dt), worst file
    warnings: list[str] = field(default_factory=list)
    #: per joint, the position range in encoder counts (largest over the files; data.position_counts)
    position_counts: np.ndarray | None = None
    #: (N, n) True where a joint sticks (conditioning.stuck_mask): friction there is not a
    #: function of velocity; velocity-friction fits should leave those rows out
    stuck: np.ndarray | None = None
    #: one dict per segment: source file, time-stamp diagnosis, period, samples, trim
    conditioning: list = field(default_factory=list)

    def __post_init__(self):
        if self.segment is None:
            self.segment = np.zeros(len(self.t), dtype=int)

    @property
    def n(self) -> int:
        return self.q.shape[1]

    @property
    def N(self) -> int:
        return self.q.shape[0]

    def __len__(self) -> int:
        return self.N

    def subset(self, index) -> "IdentData":
        """Samples ``index`` (slice, boolean mask or integer array) as a new IdentData."""
        return dataclasses.replace(
            self,
            t=self.t[index], q=self.q[index], qd=self.qd[index], qdd=self.qdd[index],
            tau=self.tau[index], segment=self.segment[index], warnings=list(self.warnings),
            stuck=None if self.stuck is None else self.stuck[index],
        )

    def segment_period(self, s) -> float:
        """Sampling period of segment ``s`` [s] (every segment is on a uniform grid)."""
        t = self.t[self.segment == s]
        return float((t[-1] - t[0]) / (len(t) - 1)) if len(t) > 1 else float(self.dt)

    def segments(self) -> list["IdentData"]:
        """One IdentData per contiguous gap-free segment."""
        return [self.subset(self.segment == s) for s in np.unique(self.segment)]

    def with_tau(self, tau: np.ndarray) -> "IdentData":
        return dataclasses.replace(self, tau=np.asarray(tau, dtype=float))

    @staticmethod
    def concatenate(parts: list["IdentData"]) -> "IdentData":
        """Stack several datasets (each keeps its own segment labels, renumbered)."""
        if not parts:
            raise DataError("no data to concatenate")
        n = parts[0].n
        for p in parts:
            if p.n != n:
                raise DataError(f"cannot combine data with {p.n} and {n} joints ({p.sources})")
        segs, offset = [], 0
        for p in parts:
            _, inv = np.unique(p.segment, return_inverse=True)
            segs.append(inv + offset)
            offset += inv.max() + 1
        cat = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
        return IdentData(
            t=cat("t"), q=cat("q"), qd=cat("qd"), qdd=cat("qdd"), tau=cat("tau"),
            dt=float(np.mean([p.dt for p in parts])), robot=parts[0].robot,
            sources=[s for p in parts for s in p.sources], filter=parts[0].filter,
            segment=np.concatenate(segs), jitter=max(p.jitter for p in parts),
            warnings=[w for p in parts for w in p.warnings],
            position_counts=None if any(p.position_counts is None for p in parts)
            else np.max([p.position_counts for p in parts], axis=0),
            stuck=None if any(p.stuck is None for p in parts) else np.concatenate([p.stuck for p in parts]),
            conditioning=[c for p in parts for c in p.conditioning],
        )

    def summary(self) -> dict:
        return {
            "samples": int(self.N), "joints": int(self.n), "dt": float(self.dt),
            "jitter": float(self.jitter), "sources": list(self.sources),
            "filter": self.filter.to_dict(),
            "q_range": [[float(a), float(b)] for a, b in zip(self.q.min(0), self.q.max(0))],
            "qd_max": [float(x) for x in np.abs(self.qd).max(0)],
            "tau_max": [float(x) for x in np.abs(self.tau).max(0)],
            "segments": int(len(np.unique(self.segment))),
            "stuck_fraction": None if self.stuck is None else [float(x) for x in self.stuck.mean(0)],
            "conditioning": list(self.conditioning),
        }


# --------------------------------------------------------------------------- reading
def pooled_autocorrelation(residual: np.ndarray, segment: np.ndarray | None = None) -> np.ndarray:
    """Autocorrelation rho (L, n) of a residual (N, n) at lags 0..L-1, pooled over the gap-free
    segments (sum of lagged products of the de-meaned segments over their sum of squares, by FFT);
    L = half the shortest segment (at least 1)."""
    r = np.asarray(residual, float)
    r = r[:, None] if r.ndim == 1 else r
    seg = np.zeros(len(r), int) if segment is None else np.asarray(segment)
    idxs = [np.nonzero(seg == s)[0] for s in np.unique(seg)]
    max_lag = max(1, min(len(i) for i in idxs) // 2)
    acc = np.zeros((max_lag, r.shape[1]))
    for idx in idxs:
        x = r[idx] - r[idx].mean(axis=0)
        nfft = 1 << int(np.ceil(np.log2(2 * len(x))))
        F = np.fft.rfft(x, nfft, axis=0)
        acc += np.fft.irfft(np.abs(F) ** 2, nfft, axis=0)[:max_lag]
    return acc / np.maximum(acc[0], 1e-300)


def decimation(data: IdentData) -> int:
    """Samples per independent sample after the low-pass, round(1 / (2 f_c dt)) (>= 1): N /
    decimation is the effective count the residual tests use."""
    fc = data.filter.cutoff_hz
    if fc is None:
        return 1
    return max(1, int(round(1.0 / (2.0 * fc * data.dt))))


def _numbered(columns: list[str], prefix: str) -> list[str]:
    """Columns ``prefix1, prefix2, ...`` in index order (stops at the first gap)."""
    out, i = [], 1
    while f"{prefix}{i}" in columns:
        out.append(f"{prefix}{i}")
        i += 1
    return out


def detect_format(columns: list[str]) -> str:
    if "time" in columns and "pos_meas1" in columns:
        return "dfki"
    if "t" in columns and "q1" in columns:
        return "canonical"
    raise DataError(
        "unrecognised CSV columns "
        f"{columns[:12]}{'...' if len(columns) > 12 else ''}: expected the canonical "
        "'t, q1..qn, tau1..taun [, qd1..qdn, qdd1..qddn]' or the DFKI "
        "'time, pos_meas*, vel_meas*, tau_con*, tau_meas*'"
    )


#: the last files read (key: device, inode, size, mtime; a FIFO or /dev/fd pipe by device and inode
#: alone): a second load of the same file (the instruments, the cut-off sweep) reuses the text
#: instead of reading it again -- a pipe can be read only once
_TEXT_CACHE: dict = {}
_TEXT_CACHE_SIZE = 8


def _file_key(path: str):
    import stat

    st = os.stat(path)
    if stat.S_ISREG(st.st_mode):
        return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
    return (st.st_dev, st.st_ino)


def read_text(path: str) -> str:
    """The file's text, read once (also from a FIFO or a process substitution ``<(...)``):
    gzip-compressed files are decompressed; UTF-8 (with or without BOM), else Latin-1 (one byte
    per character, so an odd byte in a column name never refuses the numbers); DataError for
    other binary content (named: zip, xz, bzip2, NUL bytes)."""
    import gzip

    try:
        key = _file_key(path)
    except OSError as exc:
        raise DataError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    if key in _TEXT_CACHE:
        return _TEXT_CACHE[key]
    try:
        with open(path, "rb") as fh:
            blob = fh.read()
    except OSError as exc:
        raise DataError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    if blob[:2] == b"\x1f\x8b":
        try:
            blob = gzip.decompress(blob)
        except (OSError, EOFError) as exc:
            raise DataError(f"{path}: a damaged gzip file ({exc})") from exc
    for magic, kind in ((b"PK\x03\x04", "a zip archive"), (b"\xfd7zXZ", "xz-compressed"), (b"BZh", "bzip2-compressed"),
                        (b"PAR1", "a Parquet file"), (b"\x89HDF", "an HDF5 file")):
        if blob.startswith(magic):
            raise DataError(f"{path}: {kind}, not a CSV text file: extract or export it as CSV first")
    if b"\x00" in blob[:65536]:
        raise DataError(f"{path}: binary content (NUL bytes), not a CSV text file")
    try:
        text = blob.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = blob.decode("latin-1")
    if len(_TEXT_CACHE) >= _TEXT_CACHE_SIZE:
        _TEXT_CACHE.pop(next(iter(_TEXT_CACHE)))
    _TEXT_CACHE[key] = text
    return text


def _split_lines(text: str) -> list[str]:
    """Lines of ``text`` split at LF, CRLF or CR only (str.splitlines would also split at the
    Latin-1 byte 0x85 and other separators a CSV field may hold)."""
    import re

    lines = re.split(r"\r\n|\r|\n", text)
    if lines and lines[-1] == "":
        lines.pop()
    return lines


def _header_fields(line: str) -> list[str]:
    import csv

    row = next(csv.reader([line]), [])
    cols = [c.strip() for c in row]
    while cols and cols[-1] == "":  # a trailing comma (an empty last column) is not a column
        cols.pop()
    return cols


def _check_header(path: str, cols: list[str]) -> list[str]:
    """Refuse a repeated column name (pandas would rename a second copy and ignore it)."""
    dup = [c for i, c in enumerate(cols) if c in cols[:i]]
    if dup:
        c = dup[0]
        role = ""
        if c in ("t", "time"):
            role = "the time column "
        elif (c.startswith("q") and c[1:].isdigit()) or c.startswith("pos_meas"):
            role = "the position column "
        elif c.startswith("tau") or c.startswith("qd") or c.startswith("vel_meas"):
            role = "the column "
        raise DataError(
            f"{path}: {role}{c!r} appears {cols.count(c)} times in the header (duplicate columns "
            f"{sorted(set(dup))}); a reader would silently use only one copy: rename or remove the "
            "duplicate (wrong joint numbering when the file was written?)"
        )
    return cols


def read_header(path: str) -> list[str]:
    """The header line of a CSV as written (stripped names; comment lines ``#...`` and blank lines
    before it skipped), read without pandas.

    pandas renames a repeated name (``q1``, ``q1`` -> ``q1``, ``q1.1``) and the second copy
    would then be ignored, so duplicates are detected here on the raw line and refused.
    """
    path = os.fspath(path)
    for line in _split_lines(read_text(path)):
        if line.strip() and not line.lstrip().startswith("#"):
            return _check_header(path, _header_fields(line))
    raise DataError(f"{path}: empty file (no header line)")


def _parse(path: str) -> tuple[list[str], "object", np.ndarray, list[str]]:
    """(header, DataFrame of the data lines, file line number of each data row, messages, the data
    lines' text): the
    text read once (:func:`read_text`), comment lines (``#`` first) and blank lines skipped and
    counted, a last line without its newline left out (a writer stopped mid-line)."""
    import io

    import pandas as pd

    lines = _split_lines(read_text(path))
    text_ends = read_text(path).endswith(("\n", "\r"))
    msgs: list[str] = []
    header, keep, comments = None, [], []
    for i, line in enumerate(lines):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            comments.append(i + 1)
            continue
        if header is None:
            header = (i + 1, line)
        else:
            keep.append(i)
    if header is None:
        raise DataError(f"{path}: empty file (no header line)")
    cols = _check_header(path, _header_fields(header[1]))
    name = os.path.basename(path)
    if comments and any(c > header[0] for c in comments):
        inside = [c for c in comments if c > header[0]]
        msgs.append(f"{name}: {len(inside)} comment line(s) among the data skipped (file lines "
                    f"{inside[:5]}{' ...' if len(inside) > 5 else ''}); check that nothing was pasted into the log")
    if keep and not text_ends and len(keep) > 1:
        last = keep.pop()
        msgs.append(f"{name}: the file does not end with a newline: its last line (file line {last + 1}) may have "
                    "been cut off mid-write (a number cut short reads as another value) and is left out")
    body = "\n".join(lines[i] for i in keep)
    try:
        df = pd.read_csv(io.StringIO(body), header=None, skip_blank_lines=False) if keep else pd.DataFrame()
    except Exception as exc:  # pandas raises several types for garbage
        import re

        line_hint = ""
        m = re.search(r"line (\d+)", str(exc))
        if m and int(m.group(1)) - 1 < len(keep):
            line_hint = f" (file line {keep[int(m.group(1)) - 1] + 1})"
        raise DataError(f"{path}: cannot read as CSV{line_hint}: {exc}") from exc
    if df.shape[1] > len(cols):  # trailing commas: empty extra fields are harmless, anything else is not
        tail = df.iloc[:, len(cols):]
        filled = tail.notna().any(axis=1).to_numpy()
        if filled.any():
            raise DataError(f"{path}: the header has {len(cols)} columns but file line {keep[int(filled.argmax())] + 1} "
                            f"has {df.shape[1]} values")
        df = df.iloc[:, :len(cols)]
    texts = [lines[i] for i in keep]
    return cols, df, np.asarray(keep, int) + 1, msgs, texts


def _numeric(path: str, df, cols: list[str], names: list[str], lines: np.ndarray, texts: list[str]) -> np.ndarray:
    """The columns ``names`` as floats; DataError naming the file line of the first value that is
    no number (stray text) or missing (a line with fewer values than the header)."""
    import pandas as pd

    idx = [cols.index(c) for c in names]
    if any(i >= df.shape[1] for i in idx):
        raise DataError(f"{path}: the header has {len(cols)} columns but the data lines {df.shape[1]}")
    out = np.empty((len(df), len(idx)))
    for k, i in enumerate(idx):
        col = df.iloc[:, i]
        if not pd.api.types.is_numeric_dtype(col):  # text in the column (object or string dtype)
            num = pd.to_numeric(col.astype(str).str.strip(), errors="coerce")
            bad = (num.isna() & col.notna() & ~col.astype(str).str.strip().str.lower().isin(["nan", "+nan", "-nan", ""])).to_numpy()
            if bad.any():
                r = int(bad.argmax())
                raise DataError(f"{path}: column {names[k]!r} at file line {lines[r]} holds "
                                f"{str(col.iloc[r]).strip()[:40]!r}, not a number")
            col = num
        out[:, k] = col.to_numpy(dtype=float)
    missing = np.isnan(out).any(axis=1)
    if missing.any():
        r = int(missing.argmax())
        fields = len(next(__import__("csv").reader([texts[r]]), []))
        if fields < len(cols):
            raise DataError(f"{path}: file line {lines[r]} has {fields} values, the header {len(cols)} (a line cut "
                            f"short?); {int(missing.sum())} row(s) with missing values")
    return out


def read_csv(path: str, torque: str = "tau_meas") -> RawData:
    """Read a canonical or DFKI CSV into :class:`RawData` (no filtering; checks columns).

    ``torque`` selects the DFKI torque column family (``tau_meas`` or ``tau_con``); it is
    ignored for canonical files (always ``tau*``). The file is read once (a FIFO or a process
    substitution works; :func:`read_text`); ``RawData.lines`` holds each row's file line and
    ``RawData.notes`` what was skipped (comments, a cut last line).
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise DataError(f"{path}: no such file")
    if os.path.isdir(path):
        raise DataError(f"{path}: is a folder, not a CSV file")
    cols, df, lines, notes, texts = _parse(path)
    fmt = detect_format(cols)
    if fmt == "canonical":
        tcol, qcols, taucols = "t", _numbered(cols, "q"), _numbered(cols, "tau")
        qdcols, qddcols = _numbered(cols, "qd"), _numbered(cols, "qdd")
        torque_column = "tau"
        extra_q = [c for c in cols if c.startswith("q") and c[1:].isdigit() and c not in qcols]
        extra_tau = [c for c in cols if c.startswith("tau") and c[3:].isdigit() and c not in taucols]
        for label, extra, have in (("position", extra_q, qcols), ("torque", extra_tau, taucols)):
            if extra:
                raise DataError(f"{path}: {label} columns not numbered 1..n without gaps: {have + extra} (the "
                                f"columns of joint n are q<n>, tau<n>, n = 1, 2, ...; {extra[0]!r} follows a gap)")
    else:
        if torque not in ("tau_meas", "tau_con"):
            raise DataError(f"torque must be 'tau_meas' or 'tau_con', got {torque!r}")
        tcol, qcols, taucols = "time", _numbered(cols, "pos_meas"), _numbered(cols, torque)
        qdcols, qddcols = [], []  # vel_meas is a raw finite difference: recomputed instead
        torque_column = torque
    n = len(qcols)
    if not taucols:
        raise DataError(f"{path}: no torque columns ({'tau1..' if fmt == 'canonical' else torque + '1..'})")
    if len(taucols) != n:
        raise DataError(f"{path}: {n} position columns but {len(taucols)} torque columns")
    for name, group in (("qd", qdcols), ("qdd", qddcols)):
        if group and len(group) != n:
            raise DataError(f"{path}: {n} position columns but {len(group)} {name} columns")

    def arr(names):
        return _numeric(path, df, cols, names, lines, texts) if names else None

    raw = RawData(
        t=arr([tcol])[:, 0] if len(df) else np.zeros(0), q=arr(qcols), tau=arr(taucols),
        qd=arr(qdcols) if qdcols else None, qdd=arr(qddcols) if qddcols else None, source=path, fmt=fmt,
        torque_column=torque_column,
        columns={"t": [tcol], "q": qcols, "tau": taucols, "qd": qdcols, "qdd": qddcols},
    )
    raw.lines, raw.notes = lines, notes
    return raw


def write_canonical_csv(path, t, q, tau, qd=None, qdd=None) -> str:
    """Write the canonical CSV (``t, q1..qn, [qd1..qdn, qdd1..qddn,] tau1..taun``)."""
    import pandas as pd

    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[1]
    data = {"t": np.asarray(t, dtype=float)}
    for i in range(n):
        data[f"q{i + 1}"] = q[:, i]
    for name, a in (("qd", qd), ("qdd", qdd)):
        if a is not None:
            for i in range(n):
                data[f"{name}{i + 1}"] = np.asarray(a, dtype=float)[:, i]
    for i in range(n):
        data[f"tau{i + 1}"] = np.asarray(tau, dtype=float)[:, i]
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    pd.DataFrame(data).to_csv(path, index=False, float_format="%.10g")
    return os.fspath(path)


# --------------------------------------------------------------------------- validation
def _check_values(raw: RawData) -> None:
    """DataError on a NaN/inf or an absurd value (|x| > MAX_ABS_VALUE) in any column."""
    src = raw.source
    for name in ("t", "q", "tau", "qd", "qdd"):
        a = getattr(raw, name)
        if a is None:
            continue
        a2 = a.reshape(len(a), -1)
        names = raw.columns.get(name) or [f"{name}{i + 1}" for i in range(a2.shape[1])]
        bad = ~np.isfinite(a2)
        if bad.any():
            rows = np.unique(np.nonzero(bad)[0])
            col = names[int(np.nonzero(bad[rows[0]])[0][0])]
            raise DataError(
                f"{src}: {int(bad.sum())} NaN/inf values, first in column {col!r} at data row "
                f"{rows[0] + 1} (file line {raw.line(int(rows[0]))}; rows {(rows[:5] + 1).tolist()});"
                " clean or cut the file, nothing is dropped silently"
            )
        if name == "t":
            continue  # time stamps may be large (epoch seconds); its steps are checked below
        big = np.abs(a2) > MAX_ABS_VALUE
        if big.any():
            r, c = (int(x[0]) for x in np.nonzero(big))
            raise DataError(
                f"{src}: absurd value {a2[r, c]:.4g} in column {names[c]!r} at data row {r + 1} "
                f"(file line {raw.line(r)}): |x| > {MAX_ABS_VALUE:g} in SI units (rad, rad/s, rad/s^2, N m) "
                f"is no measurement; {int(big.sum())} such values in the file"
            )


def _check_time(raw: RawData) -> np.ndarray:
    """DataError unless time strictly increases in seconds (median step below
    MAX_SAMPLE_PERIOD_S); returns the steps ``diff(t)`` [s]."""
    src = raw.source
    dt = np.diff(raw.t)
    if (dt <= 0).any():
        k = int(np.argmax(dt <= 0))
        raise DataError(
            f"{src}: time is not strictly increasing at row {k + 1} "
            f"(t={raw.t[k]:.6g} then {raw.t[k + 1]:.6g})"
        )
    dt_med = float(np.median(dt))
    if dt_med > MAX_SAMPLE_PERIOD_S:
        # the unit that puts the sampling period between 0.1 ms and 0.1 s (10 Hz .. 10 kHz)
        unit = next(((name, f) for name, f in (("milliseconds", 1e3), ("microseconds", 1e6), ("nanoseconds", 1e9))
                     if 1e-4 <= dt_med / f <= MAX_SAMPLE_PERIOD_S), None)
        if unit is None:
            raise DataError(
                f"{src}: the time column steps by {dt_med:g} (median): {1.0 / dt_med:.3g} Hz if it were seconds, "
                "and no unit (ms, us, ns) makes it a usual sampling rate; identification needs the time in seconds "
                f"with a sampling period below {MAX_SAMPLE_PERIOD_S:g} s")
        name, f = unit
        raise DataError(
            f"{src}: time looks like {name}: the time column steps by {dt_med:g} (median), i.e. "
            f"{1.0 / dt_med:.3g} Hz if it were seconds; convert it to seconds (divide by {f:g} for "
            f"{f / dt_med:.4g} Hz). Identification needs a sampling period below "
            f"{MAX_SAMPLE_PERIOD_S:g} s"
        )
    return dt


def velocity_unit_warnings(raw) -> list[str]:
    """Logged velocity columns against the derivative of the logged positions (same units?)."""
    if raw.qd is None:
        return []
    dq = np.gradient(raw.q, raw.t, axis=0)
    out = []
    for j in range(raw.q.shape[1]):
        den = float(raw.qd[:, j] @ raw.qd[:, j])
        if den <= 0:
            continue
        slope = float(dq[:, j] @ raw.qd[:, j]) / den
        if not 1.0 / VELOCITY_SLOPE_TOL <= slope <= VELOCITY_SLOPE_TOL:
            hint = " (positions in degrees, velocities in rad/s?)" if 40 < slope < 80 else ""
            out.append(f"{os.path.basename(raw.source)}: joint {j + 1}: d({column_name(raw, 'q', j)})/dt is "
                       f"{slope:.3g} x the logged velocity {column_name(raw, 'qd', j)}{hint}")
    return out


def column_name(raw: RawData, kind: str, j: int) -> str:
    """The file's name of joint ``j``'s (0-based) ``kind`` column ("q", "qd", "tau"): e.g. ``q2`` or
    ``pos_meas2`` (the file's own names, quoted beside the joint number from 1)."""
    names = raw.columns.get(kind) or []
    return names[j] if j < len(names) else f"{kind}{j + 1}"


def validate_raw(raw: RawData, n_joints: int | None = None, allow_degrees: bool = False) -> dict:
    """Check one file; raise :class:`DataError` on anything unusable. Returns timing stats.

    Returns ``{"dt": mean step, "jitter": std(dt)/mean(dt), "max_dt": ..., "warnings": [...]}``.
    """
    src = raw.source
    warns: list[str] = []
    N = len(raw.t)
    if N < MIN_SAMPLES:
        raise DataError(f"{src}: only {N} samples; need at least {MIN_SAMPLES}")
    if n_joints is not None and raw.n != n_joints:
        raise DataError(f"{src}: {raw.n} joints in the file but the robot has {n_joints}")
    _check_values(raw)
    dt = _check_time(raw)
    jitter = float(np.std(dt) / np.mean(dt))
    # jitter and gaps are handled, not refused: conditioning.py splits at gaps and puts every
    # stretch on a uniform grid (prepare); the messages come from there
    span = np.ptp(raw.q, axis=0)
    for i in range(raw.n):
        if span[i] == 0.0:
            raise DataError(f"{src}: position column {column_name(raw, 'q', i)} (joint {i + 1}) is constant; the joint "
                            "never moved (wrong column?)")
    tau_span = np.ptp(raw.tau, axis=0)
    if np.all(tau_span == 0.0):
        raise DataError(f"{src}: every torque column is constant; nothing drives the motion")
    for i in range(raw.n):
        if tau_span[i] == 0.0:
            warns.append(
                f"{os.path.basename(src)}: torque column {column_name(raw, 'tau', i)} "
                f"is constant ({raw.tau[0, i]:g} N m): joint {i + 1} treated as unpowered"
            )
    counts = position_counts(raw.q)
    warns = list(getattr(raw, "notes", None) or []) + warns
    warns += velocity_unit_warnings(raw)
    peak = np.abs(raw.q).max(axis=0)
    if not allow_degrees and (peak > DEGREE_THRESHOLD_RAD).any():
        i = int(np.argmax(peak))
        raise DataError(f"{src}: |{column_name(raw, 'q', i)}| (joint {i + 1}) reaches {peak[i]:.4g}, more than two turns: "
                        + position_unit_cause(raw.q[:, i]))
    return {"dt": float(np.mean(dt)), "jitter": jitter, "max_dt": float(dt.max()), "warnings": warns,
            "counts": counts}


def position_unit_cause(q: np.ndarray) -> str:
    """What a position column that exceeds two turns most likely holds (for the error message):
    raw encoder counts (whole numbers), a multi-turn offset (it moves less than two turns about a
    value far from 0), or degrees (it moves more than two turns)."""
    q = np.asarray(q, float)
    span, centre = float(np.ptp(q)), float(np.median(q))
    whole = np.all(q == np.round(q))
    if whole and span > 100:
        return (f"the values are whole numbers over a span of {span:.0f}: raw encoder counts? convert to rad "
                "(x 2 pi / counts per revolution)")
    if span <= DEGREE_THRESHOLD_RAD:
        turns = centre / (2 * np.pi)
        return (f"it moves only {span:.3g} about {centre:.4g}: degrees (a small motion: convert to rad, x pi / 180), "
                f"or a multi-turn encoder offset of about {turns:.1f} turns (subtract it, so that q = 0 is the URDF's zero)")
    if span <= 4 * 360.0:
        return (f"it moves over {span:.4g}: positions look like degrees (convert to rad, x pi / 180)")
    return f"it moves over {span:.4g}: positions are not in rad (degrees? encoder counts?): convert to rad"


def position_counts(q: np.ndarray) -> np.ndarray:
    """Range of each position column in encoder counts: ``ptp(q_j) / quantum_j``.

    The quantum of a column is its smallest non-zero step ``min |q_j[k+1] - q_j[k]| > 0``
    (the encoder resolution of a quantised log; for unquantised data it is tiny and the count
    huge). A joint whose range is at most :data:`FROZEN_MAX_COUNTS` counts carries no
    information about its dynamics (see :func:`frozen_joints`).
    """
    q = np.asarray(q, float).reshape(len(q), -1)
    out = np.empty(q.shape[1])
    for j in range(q.shape[1]):
        steps = np.abs(np.diff(q[:, j]))
        steps = steps[steps > 0]
        span = float(np.ptp(q[:, j]))
        out[j] = 0.0 if steps.size == 0 else span / float(steps.min())
    return out


def frozen_joints(data: "IdentData") -> list[int]:
    """0-based joints whose position stays within FROZEN_MAX_COUNTS encoder counts in every file."""
    if data.position_counts is None:
        return []
    return [j for j, c in enumerate(data.position_counts) if c <= FROZEN_MAX_COUNTS + 1e-6]


# --------------------------------------------------------------------------- filtering
def zero_phase_lowpass(x: np.ndarray, dt: float, cutoff_hz: float | None, order: int = DEFAULT_FILTER_ORDER):
    """Zero-phase Butterworth low-pass along axis 0 (``filtfilt``; identity if cutoff None)."""
    if cutoff_hz is None:
        return np.array(x, dtype=float, copy=True)
    from scipy.signal import butter, filtfilt

    nyq = 0.5 / dt
    if not 0.0 < cutoff_hz < nyq:
        raise DataError(f"filter cut-off {cutoff_hz} Hz must lie in (0, Nyquist = {nyq:.4g} Hz)")
    b, a = butter(order, cutoff_hz / nyq)
    padlen = min(3 * max(len(a), len(b)) * 10, x.shape[0] - 1)
    return filtfilt(b, a, x, axis=0, padlen=padlen)


def differentiate(t, x: np.ndarray) -> np.ndarray:
    """Central differences (second order, one-sided at the ends) along axis 0.

    ``t`` is the uniform sampling period (a float, the only use in :func:`prepare`: derivatives
    are taken on a uniform grid only) or, for callers with their own grid, the time stamps."""
    return np.gradient(x, t, axis=0, edge_order=2)


def _condition_file(r: RawData, k: int, stats: dict, cutoff_hz, order, robot, trim_s, given: bool,
                    velocities: str) -> tuple[list["IdentData"], list[str]]:
    """One file -> one IdentData per usable gap-free segment (conditioning.py), plus messages."""
    from robust_drake.identification import conditioning as C

    name = os.path.basename(r.source)
    msgs: list[str] = []
    pieces = C.split_at_gaps(r.t)
    if len(pieces) > 1:
        dt_all = np.diff(r.t)
        gaps = [float(dt_all[p.start - 1]) for p in pieces[1:]]
        msgs.append(
            f"{name}: {len(gaps)} logging gap(s) (longest {max(gaps) * 1e3:.3g} ms; a gap is a step > "
            f"{C.GAP_FACTOR:g} x the median {np.median(dt_all) * 1e3:.3g} ms): split into {len(pieces)} segments")
    pieces, jump_msgs = _split_at_jumps(r, pieces)
    msgs += jump_msgs
    out, dropped = [], []
    for piece in pieces:
        t = r.t[piece]
        if len(t) < 4:
            dropped.append((len(t), float(r.t[piece.start])))
            continue
        arrays = {"q": r.q[piece], "tau": r.tau[piece],
                  "qd": None if r.qd is None else r.qd[piece], "qdd": None if r.qdd is None else r.qdd[piece]}
        grid, arr, diag, m_msgs = C.condition_stretch(t, arrays, name)
        msgs += m_msgs
        T = diag.period
        m = int(round(trim_s / T))
        if len(grid) - 2 * m < MIN_SAMPLES:
            dropped.append((len(grid), float(grid[0])))
            continue
        if given:
            q, qd, qdd, tau = arr["q"], arr["qd"], arr["qdd"], arr["tau"]
            # given derivatives are used as given, but checked against the derivatives of the
            # positions / velocities in the default band (a given acceleration that is not the
            # motion warns)
            lp = lambda x: zero_phase_lowpass(x, T, min(DEFAULT_CUTOFF_HZ, 0.4 / T), order)  # noqa: E731
            inner = slice(m + 1, len(grid) - m - 1) if m else slice(int(0.25 / T), len(grid) - int(0.25 / T))
            if len(range(*inner.indices(len(grid)))) >= MIN_SAMPLES:
                msgs += C.agreement(lp(qd)[inner], differentiate(T, lp(q))[inner], "given velocity qd",
                                    "the derivative of q", name)
                msgs += C.agreement(lp(qdd)[inner], differentiate(T, lp(qd))[inner],
                                    "given acceleration qdd", "the derivative of qd", name)
        else:
            q = zero_phase_lowpass(arr["q"], T, cutoff_hz, order)
            tau = zero_phase_lowpass(arr["tau"], T, cutoff_hz, order)
            qd_q = differentiate(T, q)
            if velocities == "logged":
                qd = zero_phase_lowpass(arr["qd"], T, cutoff_hz, order)
                msgs += C.velocity_agreement(qd[m:len(grid) - m], qd_q[m:len(grid) - m], name)
            else:
                qd = qd_q
            qdd = differentiate(T, qd)
        keep = slice(m, len(grid) - m)
        msgs += C.derivative_consistency(qd[keep], qdd[keep], None if given else cutoff_hz, T, name)
        stuck = C.stuck_mask(qd[keep], tau[keep], T)
        nk = len(grid) - 2 * m
        out.append(IdentData(
            t=grid[keep].copy(), q=q[keep], qd=qd[keep], qdd=qdd[keep], tau=tau[keep], dt=T, robot=robot,
            sources=[r.source], segment=np.full(nk, k), jitter=stats["jitter"], warnings=[],
            position_counts=stats["counts"], stuck=stuck,
            conditioning=[{"source": name, "start_s": float(grid[0]), "samples": int(nk), "trim_samples": m,
                           "stamps": diag.to_dict()}],
        ))
        out[-1].filter.trim_samples = m
    if dropped:
        msgs.append(
            f"{name}: {len(dropped)} segment(s) too short for the filters dropped (fewer than {MIN_SAMPLES} "
            f"samples after trimming {trim_s:.3g} s at each end; lengths {[d[0] for d in dropped][:6]})")
    return out, msgs


def _split_at_jumps(r: RawData, pieces: list[slice]) -> tuple[list[slice], list[str]]:
    """Position jumps no motion of the log makes (conditioning.position_jumps): a wrapped angle
    (a whole number of turns) is unwrapped in ``r.q`` (the motion continues through it), any other
    jump splits its piece there (two logs joined with shifted stamps, an encoder glitch); one
    message each."""
    from robust_drake.identification import conditioning as C

    name = os.path.basename(r.source)
    msgs, cuts = [], set()
    jumps = C.position_jumps(r.q)
    for k, j, step, z in jumps:
        col = column_name(r, "q", j)
        where = f"between file lines {r.line(k)} and {r.line(k + 1)}"
        if C.is_wrap(step):
            turns = int(round(step / (2 * np.pi)))
            r.q[k + 1:, j] -= 2 * np.pi * turns
            msgs.append(f"{name}: {col} (joint {j + 1}) jumps by {step:.4g} rad ({turns:+d} turn(s)) {where}: a wrapped "
                        "angle; unwrapped (the positions after it shifted by a whole number of turns)")
        else:
            cuts.add(k + 1)
            msgs.append(f"{name}: {col} (joint {j + 1}) jumps by {step:.4g} rad in one step {where} ({z:.0f} x the spread "
                        "of its step changes; no motion of this log makes that step): two logs joined, or an encoder "
                        "glitch? the file is split into segments there")
    if not cuts:
        return pieces, msgs
    out = []
    for p in pieces:
        edges = [p.start] + sorted(c for c in cuts if p.start < c < p.stop) + [p.stop]
        out += [slice(a, b) for a, b in zip(edges[:-1], edges[1:])]
    return out, msgs


def filter_settling_s(dt: float, cutoff_hz: float | None, order: int = DEFAULT_FILTER_ORDER,
                      level: float = 0.01) -> float:
    """Half-width [s] of the zero-phase low-pass's impulse response (:func:`zero_phase_lowpass`):
    the time from its centre beyond which |h| stays below ``level`` x its peak. A filtered sample
    depends on the raw signal within that distance (0 without a filter). Measured: 0.22 s at
    8 Hz, order 4, 250 Hz."""
    if not cutoff_hz:
        return 0.0
    h, half = _impulse_response(dt, cutoff_hz, order)
    h = np.abs(h)
    big = np.nonzero(h >= level * h.max())[0]
    return float(max(half - big[0], big[-1] - half) * dt)


def _impulse_response(dt: float, cutoff_hz: float, order: int) -> tuple[np.ndarray, int]:
    """The zero-phase low-pass's response to a unit impulse at the centre of 2 half + 1 samples
    (half = 8 / (f_c dt): long past its settling), and that centre index."""
    half = int(math.ceil(8.0 / (cutoff_hz * dt)))
    x = np.zeros(2 * half + 1)
    x[half] = 1.0
    return zero_phase_lowpass(x[:, None], dt, cutoff_hz, order)[:, 0], half


def filter_main_lobe_s(dt: float, cutoff_hz: float | None, order: int = DEFAULT_FILTER_ORDER) -> float:
    """Half-width [s] of the main lobe of the zero-phase low-pass's impulse response (its first
    zero from the centre; 0 without a filter): how far one raw torque step is spread before the
    response changes sign. Measured: 0.062 s at 8 Hz, order 4 (about 1 / (2 f_c)) at 500 Hz to
    2500 Hz, 0.07 s at 100 Hz."""
    if not cutoff_hz:
        return 0.0
    h, half = _impulse_response(dt, cutoff_hz, order)
    neg = np.nonzero(h[half:] <= 0.0)[0]
    return float((neg[0] if neg.size else half) * dt)


def reversal_half_width_s(data: "IdentData", s=None) -> float:
    """Half-width w [s] of the rows around a velocity reversal where the filtered velocity does
    not resolve the friction state: a stick shorter than the stuck-row rule's
    ``conditioning.STICK_MIN_S`` (so not marked stuck) centred on the zero crossing, spread by
    the filter's main lobe (:func:`filter_main_lobe_s`): w = STICK_MIN_S / 2 + lobe (0.112 s at
    8 Hz)."""
    from robust_drake.identification import conditioning as C

    dt = data.segment_period(s) if s is not None else float(data.dt)
    cutoff = data.filter.cutoff_hz if data.filter.derivatives != "given" else None
    return 0.5 * C.STICK_MIN_S + filter_main_lobe_s(dt, cutoff, data.filter.order or 1)


def reversal_rows(data: "IdentData", joint: int) -> np.ndarray:
    """(N,) bool: rows of ``joint`` within :func:`reversal_half_width_s` of a sign change of its
    filtered velocity (same segment), or stuck (``IdentData.stuck``). There a sign(qd) column and
    any smooth friction shape are told apart only by how the joint passes through zero speed
    (short sticks, the filter's spread of the friction step), not by friction vs velocity."""
    out = np.zeros(data.N, bool) if data.stuck is None else np.array(data.stuck[:, joint], bool)
    for s in np.unique(data.segment):
        idx = np.nonzero(data.segment == s)[0]
        v = data.qd[idx, joint]
        flips = np.nonzero(np.sign(v[1:]) != np.sign(v[:-1]))[0]
        if flips.size == 0:
            continue
        w = int(round(reversal_half_width_s(data, s) / data.segment_period(s)))
        cover = np.zeros(len(idx) + 1, int)
        np.add.at(cover, np.maximum(flips - w + 1, 0), 1)
        np.add.at(cover, np.minimum(flips + w + 1, len(idx)), -1)
        out[idx] |= np.cumsum(cover)[:-1] > 0
    return out


def friction_exclusion(data: "IdentData") -> np.ndarray | None:
    """(N, n) bool: the rows of joint j's equation that a velocity-friction fit must leave out.

    Where a joint sticks (``IdentData.stuck``) its friction balances whatever torque is applied
    and is not a function of velocity, and the zero-phase filter spreads that torque over
    :func:`filter_settling_s` on either side: the stuck run widened by that time, within its
    segment. Only that joint's rows (the friction of joint j enters equation j alone). None when
    nothing sticks."""
    if data.stuck is None or not data.stuck.any():
        return None
    cutoff = data.filter.cutoff_hz if data.filter.derivatives != "given" else None
    out = np.zeros_like(data.stuck, dtype=bool)
    for s in np.unique(data.segment):
        idx = np.nonzero(data.segment == s)[0]
        w = int(round(filter_settling_s(data.segment_period(s), cutoff, data.filter.order or 1)
                      / data.segment_period(s)))
        st = data.stuck[idx]
        for j in range(data.n):
            run = np.nonzero(st[:, j])[0]
            if run.size == 0:
                continue
            cover = np.zeros(len(idx) + 1, int)
            np.add.at(cover, np.maximum(run - w, 0), 1)
            np.add.at(cover, np.minimum(run + w + 1, len(idx)), -1)
            out[idx, j] = np.cumsum(cover)[:-1] > 0
    return out


def exclusion_messages(data: "IdentData", exclude: np.ndarray | None, joint_names=None) -> list[str]:
    """One line per joint with rows left out by :func:`friction_exclusion` (for report warnings)."""
    if exclude is None:
        return []
    names = list(joint_names) if joint_names is not None else [f"joint{j + 1}" for j in range(data.n)]
    settle = filter_settling_s(data.dt, data.filter.cutoff_hz if data.filter.derivatives != "given" else None,
                               data.filter.order or 1)
    return [f"stiction: joint {j + 1} ({names[j]}) sticks on {data.stuck[:, j].mean():.1%} of the fit samples; "
            f"those rows and {settle:.2g} s of filter settling on either side ({exclude[:, j].mean():.1%} of "
            f"joint {j + 1}'s rows) are left out of joint {j + 1}'s equation in every fit and held-out score "
            "(friction there is not a function of velocity)"
            for j in range(data.n) if exclude[:, j].any()]


def _stick_messages(segs: list["IdentData"], name: str, joint_names=None) -> list[str]:
    """One message per joint stuck on more than STICK_WARN_FRAC of one file's samples (joints
    numbered from 1, with the URDF's names when given)."""
    from robust_drake.identification import conditioning as C

    stuck = np.concatenate([sg.stuck for sg in segs])
    msgs = []
    for j, f in enumerate(stuck.mean(0)):
        if f > C.STICK_WARN_FRAC:
            msgs.append(
                f"{name}: joint {j + 1}{'' if joint_names is None else f' ({joint_names[j]})'} sticks on {f:.0%} of the samples (speed < {C.STICK_SPEED:g} "
                f"rad/s for >= {C.STICK_MIN_S:g} s while its torque changes): friction there is not a "
                "function of velocity; those rows are marked (IdentData.stuck)")
    return msgs


def prepare(
    raw: RawData | list[RawData],
    cutoff_hz: float | None = DEFAULT_CUTOFF_HZ,
    order: int = DEFAULT_FILTER_ORDER,
    robot: str | None = None,
    n_joints: int | None = None,
    use_given_derivatives: bool = False,
    allow_degrees: bool = False,
    trim_s: float | None = None,
    velocities: str = "positions",
    joint_names=None,
    quiet: bool = False,
) -> IdentData:
    """Validate, condition (conditioning.py: gaps -> segments, uniform grid), filter and
    differentiate one or more files into one :class:`IdentData`.

    ``trim_s`` [s] is cut at both ends of every segment (default ``2 / cutoff_hz``); it is
    converted to samples per segment as ``round(trim_s / T_segment)`` from the raw stamps only,
    so two loads of the same files with the same ``trim_s`` keep the same rows whatever their
    cut-offs (:func:`load_companion`). ``velocities="logged"`` low-passes the log's ``qd*``
    columns instead of differentiating the positions (only for real velocity sensors).
    ``joint_names`` (the URDF's, in velocity order) name the joints in messages. ``quiet``: the
    messages go to ``IdentData.warnings`` only, not through :mod:`warnings` (a second load of
    files already loaded and reported, e.g. at another cut-off: :func:`load_companion`).
    """
    raws = raw if isinstance(raw, (list, tuple)) else [raw]
    if not raws:
        raise DataError("no data files given")
    if velocities not in ("positions", "logged"):
        raise DataError(f"velocities must be 'positions' or 'logged', got {velocities!r}")
    parts, msgs = [], []
    for k, r in enumerate(raws):
        stats = validate_raw(r, n_joints=n_joints if n_joints is not None else raws[0].n,
                             allow_degrees=allow_degrees)
        msgs += stats["warnings"]
        given = use_given_derivatives and r.qd is not None and r.qdd is not None
        if velocities == "logged" and not given and r.qd is None:
            raise DataError(
                f"{r.source}: no logged velocity columns (qd1..qd{r.n}) for velocities='logged'"
                + ("; the DFKI vel_meas columns are finite differences of pos_meas, not a sensor"
                   if r.fmt == "dfki" else ""))
        trim = trim_s if trim_s is not None else (2.0 / cutoff_hz if (cutoff_hz and not given) else 0.0)
        segs, m = _condition_file(r, k, stats, cutoff_hz, order, robot, trim, given, velocities)
        msgs += m
        if segs:
            msgs += _stick_messages(segs, os.path.basename(r.source), joint_names)
        if not segs:
            span = float(r.t[-1] - r.t[0]) if len(r.t) > 1 else 0.0
            why = (f"the filter cut-off {cutoff_hz:g} Hz trims 2 / f_c = {trim:.3g} s of filter start-up at each end of "
                   f"every segment, and the file lasts {span:.3g} s: raise the cut-off (default {DEFAULT_CUTOFF_HZ:g} Hz)"
                   if cutoff_hz and trim_s is None and not given and 2 * trim >= span else
                   f"too short ({len(r.t)} samples) to trim {trim:.3g} s of filter start-up at each end of every "
                   "segment; record longer or pass a smaller trim")
            raise DataError(f"{r.source}: {why}")
        fs = (FilterSettings(cutoff_hz=None, order=0, derivatives="given") if given
              else FilterSettings(cutoff_hz=cutoff_hz, order=order,
                                  velocities="logged velocities" if velocities == "logged" else "positions"))
        fs.trim_samples = segs[0].filter.trim_samples
        fs.trim_s = float(trim)
        for sg in segs:
            sg.filter = fs
        parts += segs
    data = IdentData.concatenate(parts) if len(parts) > 1 else parts[0]
    data.dt = float(np.mean([p.dt for p in parts]))
    data.sources = list(dict.fromkeys(data.sources))  # a file split at gaps is still one source
    data.warnings = list(dict.fromkeys(msgs))
    for w in [] if quiet else data.warnings:
        warnings.warn(w, DataWarning, stacklevel=2)
    return data


def load(
    paths, robot: str | None = None, n_joints: int | None = None, torque: str = "tau_meas",
    cutoff_hz: float | None = DEFAULT_CUTOFF_HZ, order: int = DEFAULT_FILTER_ORDER,
    use_given_derivatives: bool = False, allow_degrees: bool = False, trim_s: float | None = None,
    velocities: str = "positions", joint_names=None, quiet: bool = False,
) -> IdentData:
    """Read + validate + condition + filter one path or a list of paths (canonical or DFKI);
    ``joint_names`` and ``quiet`` as in :func:`prepare`."""
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    raws = [read_csv(p, torque=torque) for p in paths]
    return prepare(raws, cutoff_hz=cutoff_hz, order=order, robot=robot, n_joints=n_joints,
                   use_given_derivatives=use_given_derivatives, allow_degrees=allow_degrees, trim_s=trim_s,
                   velocities=velocities, joint_names=joint_names, quiet=quiet)


def load_companion(paths, like: IdentData, cutoff_hz: float | None, torque: str = "tau_meas",
                   order: int | None = None) -> IdentData:
    """The same files as ``like`` filtered at another cut-off (e.g. the instruments), on exactly
    ``like``'s rows: the same trim rule (``like.filter.trim_s``), hence the same segments and
    samples. Raises :class:`DataError` if the rows differ (they cannot, by construction)."""
    vel = "logged" if like.filter.velocities == "logged velocities" else "positions"  # as ``like``
    other = load(paths, robot=like.robot, n_joints=like.n, torque=torque, cutoff_hz=cutoff_hz,
                 order=like.filter.order if order is None else order, trim_s=like.filter.trim_s,
                 velocities=vel, quiet=True)
    same_rows(like, other)
    return other


def same_rows(a: IdentData, b: IdentData) -> None:
    """Raise :class:`DataError` unless ``a`` and ``b`` hold the same samples (segments, times)."""
    if a.N != b.N or not np.array_equal(a.segment, b.segment) or not np.allclose(a.t, b.t, rtol=0, atol=1e-9):
        raise DataError(f"two loads of the same files disagree: {a.N} vs {b.N} rows "
                        f"({a.sources}); the trim rule must be shared (data.load_companion)")


def from_arrays(t, q, tau, qd=None, qdd=None, robot=None, cutoff_hz=DEFAULT_CUTOFF_HZ,
                order=DEFAULT_FILTER_ORDER, source="<memory>") -> IdentData:
    """Build an IdentData from arrays with the same validation and convention as files."""
    raw = RawData(t=np.asarray(t, float), q=np.atleast_2d(np.asarray(q, float)),
                  tau=np.atleast_2d(np.asarray(tau, float)),
                  qd=None if qd is None else np.asarray(qd, float),
                  qdd=None if qdd is None else np.asarray(qdd, float), source=source)
    return prepare(raw, cutoff_hz=cutoff_hz, order=order, robot=robot,
                   use_given_derivatives=qd is not None and qdd is not None)
