"""The work of ``uwval compare`` without typer: the fast path of the command line.

``uwval compare`` on plain arguments (:func:`fast_compare`) parses them here and runs
:func:`run_compare`, importing neither typer (which imports pydantic and builds a validator
per option) nor rich unless a table is printed: start-up is most of the whole-command time of
a compare. The typer command in :mod:`uwval.cli.compare_cmd` calls the same function.
"""

from __future__ import annotations

import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uwval.errors import ConfigError


def _parse_offset(value: str) -> float | str:
    if value.strip().lower() == "auto":
        return "auto"
    try:
        seconds = float(value)
    except ValueError:
        raise ConfigError(f"--offset must be seconds or 'auto', got {value!r}") from None
    if not math.isfinite(seconds):
        raise ConfigError(f"--offset must be a finite number of seconds or 'auto', got {value!r}")
    return seconds


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        if v != 0 and abs(v) < 1e-3:  # keep small errors short and legible: 5.03e-04
            return f"{v:.{digits - 1}e}"
        return f"{v:.{digits}g}"
    return str(v)


def _fmt_full(v: Any, digits: int = 10) -> str:
    """A number with 10 significant digits (tables written to a file or a pipe); ``digits``
    is accepted for :func:`_fmt`'s signature and not used (never fewer than 10)."""
    if v is None:
        return "-"
    return f"{v:.10g}" if isinstance(v, float) else str(v)


def output_console() -> Any:
    """A rich Console for stdout; when stdout is not a terminal (a file, a pipe, a CI log)
    nothing is wrapped or cut: lines and tables keep their full width."""
    from rich.console import Console

    if sys.stdout is not None and sys.stdout.isatty():
        return Console()
    return Console(width=100_000, soft_wrap=True)


#: Environment variables under which rich treats a pipe or a file as a terminal.
_TERMINAL_ENV = ("FORCE_COLOR", "TTY_COMPATIBLE", "TTY_INTERACTIVE")
#: What rich could read as an emoji code (":name:") or an escape in any printed text, and
#: as a markup tag in text printed as markup.
_RICH_ANY = re.compile(r":\S*?:|\\")
_RICH_MARKUP = re.compile(r"\[[a-z#/@]|:\S*?:|\\")


@dataclass(frozen=True)
class _Line:
    """A line printed under the table: as rich markup or not, highlighted or not, after a
    yellow ``warning:`` tag or not."""

    text: str
    markup: bool = True
    highlight: bool = True
    warning: bool = False


def _plain_output() -> bool:
    """Whether stdout is a plain file or pipe, where rich prints text without styles and
    without wrapping (``output_console``'s width): then :func:`_table_text` writes the
    same characters without importing rich (~25 ms of a compare's start-up)."""
    import builtins
    import os

    if sys.stdout is None or any(k in os.environ for k in _TERMINAL_ENV):
        return False
    if hasattr(builtins, "get_ipython") or "idlelib" in sys.modules:  # Jupyter, IDLE
        return False
    try:
        return not sys.stdout.isatty()
    except ValueError:  # a closed stdout: let rich decide, as before
        return False


def _table_text(
    title: str, cols: list[str], rows: list[list[str]], lines: list[_Line]
) -> str | None:
    """What rich prints for :func:`_print_table`'s table and lines on a plain file or pipe
    (``Console(width=100_000, soft_wrap=True)``: no styles, no wrapping; box SIMPLE_HEAD,
    no edge padding; a title wider than the table is not wrapped either), or None when rich
    could print something else: text that is not printable ASCII (wide characters), or text
    rich could read as markup, an emoji code or an escape. ``title`` and the first column are
    escaped for rich (their brackets are text)."""
    escaped = [title, *cols, *(c for r in rows for c in r[:1])]
    marked = [c for r in rows for c in r[1:]]
    if not all(
        t.isascii() and t.isprintable() for t in [*escaped, *marked, *(ln.text for ln in lines)]
    ):
        return None
    if any(_RICH_ANY.search(t) for t in escaped) or any(_RICH_MARKUP.search(t) for t in marked):
        return None
    if any(
        (_RICH_MARKUP if ln.markup and not ln.warning else _RICH_ANY).search(ln.text)
        for ln in lines
    ):
        return None
    widths = [max(len(c), *(len(r[i]) for r in rows)) for i, c in enumerate(cols)]
    last = len(cols) - 1

    def row_text(cells: list[str]) -> str:
        out = []
        for i, (cell, w) in enumerate(zip(cells, widths, strict=True)):
            body = cell.ljust(w) if i == 0 else cell.rjust(w)
            out.append(("" if i == 0 else " ") + body + ("" if i == last else " "))
        return " " + " ".join(out) + " "

    inner = sum(widths) + 3 * last  # the cells, their inner padding, the separators
    parts = [title, " " * (inner + 2), row_text(cols), " " + "\u2500" * inner + " "]
    parts += [row_text(r) for r in rows]
    parts.append(" " * (inner + 2))
    parts += [("warning: " if ln.warning else "") + ln.text for ln in lines]
    return "\n".join(parts) + "\n"


def _print_table(doc: dict[str, Any], title: str) -> None:
    plain = _plain_output()
    console = None if plain else output_console()
    sync = doc.get("sync") or {}
    if sync.get("method") == "nearest":  # evo's association: say its parameter too
        title += f"  (sync nearest, max diff {sync.get('max_diff_s', 0.01):g} s, as evo)"
    elif sync.get("method"):
        title += f"  (sync {sync['method']}: Unity side interpolated at the reference stamps)"
    full = console is None or not console.is_terminal  # a file or a pipe: every column, digit
    cols = ["axis", "MAE", "RMSE", "max", "bias", "Pearson r"]
    if full:  # fits no 80-column terminal: only where nothing wraps
        cols += ["p95", "median", "std", "Pearson 95% CI", "Pearson p", "n"]
    # short on a terminal on purpose (fits 80 columns): the rest is in --json
    num = _fmt_full if full else _fmt
    rows: list[list[str]] = []
    for ax, s in doc["axes"].items():
        r = s.get("pearson_r")
        r_text = "n/a" if r is None else (_fmt_full(r) if full else f"{r:.6f}")
        unit = s.get("unit", "")
        row = [
            f"{ax} [{unit}]" if unit else ax,  # escaped for rich
            num(s["mae"]),
            num(s["rmse"]),
            num(s["max"]),
            num(s["bias"]),
            r_text,
        ]
        if full:
            ci = s.get("pearson_ci")
            row += [
                num(s.get("p95")),
                num(s.get("median")),
                num(s.get("std")),
                "n/a" if not ci or None in ci else f"[{_fmt_full(ci[0])}, {_fmt_full(ci[1])}]",
                num(s.get("pearson_p")),
                str(s.get("pearson_n", "")),
            ]
        rows.append(row)
    lines: list[_Line] = []
    undefined = [ax for ax, s in doc["axes"].items() if s.get("pearson_r") is None]
    if undefined:
        reasons = {doc["axes"][ax].get("pearson_reason") or "undefined" for ax in undefined}
        lines.append(
            _Line(
                f"Pearson r n/a for {', '.join(undefined)}: {'; '.join(sorted(reasons))}",
                highlight=False,
            )
        )
    pn, rot, counts = doc["position_error_norm"], doc["rotation_error_deg"], doc["counts"]
    lines.append(
        _Line(
            f"samples {doc['n_samples']} (matched {counts['matched']}, masked {counts['masked']}, "
            f"dropped {counts['dropped']}); sync {doc['sync']['method']}; frame "
            f"{doc['frame']['configured']}; align {doc['alignment']['mode']}"
        )
    )
    lines.append(
        _Line(
            f"position error norm [m]: rmse {num(pn['rmse'])} mean {num(pn['mean'])} "
            f"median {num(pn['median'])} max {num(pn['max'])}; rotation [deg]: rmse "
            f"{num(rot['rmse'])} max {num(rot['max'])}",
            markup=False,
        )
    )
    ape = doc.get("ape")
    if ape:  # -r/--pose_relation: evo_ape's statistics, all digits (as evo prints them)
        lines.append(
            _Line(
                f"APE w.r.t. {ape['pose_relation']} [{ape['unit']}]: "
                + " ".join(
                    f"{k} {ape[k]:.9g}"
                    for k in ("rmse", "mean", "median", "std", "min", "max", "sse")
                ),
                markup=False,
                highlight=False,
            )
        )
    off = doc["offset"]
    line = f"clock offset {num(off['applied_s'], 6)} s"
    if off.get("estimate"):
        line += f" (estimated, +/- {num(off['estimate']['uncertainty_s'], 3)} s)"
    if doc.get("latency"):
        lat = doc["latency"]
        line += f"; latency {num(lat['mean_ms'])} ms mean, {num(lat['p95_ms'])} ms p95"
    if off.get("drift_ppm"):
        line += f"; clock drift {off['drift_ppm']:+.2f} ppm removed"
    lines.append(_Line(line))
    if doc.get("lag"):  # the study's answer (uwval.comparison.lag)
        lines.append(_Line(doc["lag"]["sentence"], markup=False, highlight=False))
    lines += [_Line(w, highlight=False, warning=True) for w in doc.get("warnings", [])]
    if plain:
        text = _table_text(title, cols, rows, lines)
        if text is not None:
            sys.stdout.write(text)
            return
    _rich_table(console or output_console(), title, cols, rows, lines)


def _rich_table(
    console: Any, title: str, cols: list[str], rows: list[list[str]], lines: list[_Line]
) -> None:
    """Print the table and its lines with rich (a terminal, or text rich renders its way)."""
    from rich import box
    from rich.markup import escape
    from rich.table import Table

    table = Table(title=escape(title), title_justify="left", box=box.SIMPLE_HEAD, pad_edge=False)
    for col in cols:
        table.add_column(col, justify="left" if col == "axis" else "right", no_wrap=True)
    for row in rows:
        table.add_row(escape(row[0]), *row[1:])
    console.print(table)
    for ln in lines:
        if ln.warning:
            console.print(f"[yellow]warning:[/] {escape(ln.text)}", highlight=False)
        else:
            console.print(ln.text, markup=ln.markup, highlight=ln.highlight)


def _align_mode(align: str, evo_align: bool, correct_scale: bool, align_origin: bool) -> str:
    """--align VALUE and evo's flags (-a, -s, -as, --align_origin) -> one alignment mode."""
    flags = [f for f, on in (("-a", evo_align), ("-s", correct_scale)) if on]
    if align_origin:
        flags.append("--align_origin")
    if not flags:
        return align
    if align_origin and evo_align:
        raise ConfigError("--align_origin cannot be combined with -a (as in evo_ape)")
    mode = "origin" if align_origin else ("sim3" if correct_scale else "se3")
    if not evo_align and correct_scale:
        # evo_ape -s: the scale only; -s --align_origin: that scale, then the origin
        mode = "scale_origin" if align_origin else "scale"
    if align not in ("none", mode):
        raise ConfigError(f"--align {align} contradicts {' '.join(flags)} (which means {mode})")
    return mode


def _write_output(path: Path, data: bytes | str, what: str) -> None:
    """Write a file the user asked for; a failure is a one-line ConfigError naming it."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(data, bytes):
            path.write_bytes(data)
        else:
            path.write_text(data)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write {what}: {exc.strerror or exc}") from None


#: Columns of ``--save-errors`` (after the stamps): signed errors other - reference.
ERROR_COLUMNS = ("x", "y", "z", "roll", "pitch", "yaw", "position_norm", "rotation_angle")


def errors_csv(result: Any) -> str:
    """The per-sample errors of one :class:`ComparisonResult` as CSV text.

    One row per aligned sample: ``t_ns`` (int, reference clock), ``t_s``, then the signed
    errors other - reference: x y z (m, ENU world), roll pitch yaw (deg, wrapped), the
    position-error norm (m) and the geodesic rotation angle (deg).
    """
    import io

    import numpy as np

    errs = result.errors
    cols = np.column_stack([result.t * 1e-9] + [errs[c] for c in ERROR_COLUMNS])
    buf = io.StringIO()
    header = "t_ns,t_s," + ",".join(
        f"err_{c}_{'m' if c in ('x', 'y', 'z', 'position_norm') else 'deg'}" for c in ERROR_COLUMNS
    )
    buf.write(header + "\n")
    body = io.StringIO()
    np.savetxt(body, cols, fmt="%.17g", delimiter=",")
    stamps = result.t.astype(str)
    lines = body.getvalue().splitlines()
    buf.write("".join(f"{s},{line}\n" for s, line in zip(stamps, lines, strict=True)))
    return buf.getvalue()


def _label_paths(base: Path, names: list[str], primary: str) -> dict[str, Path]:
    """One output path per topic: ``base`` for the primary topic, base.<name>.suffix else."""
    out = {}
    for name in names:
        if name == primary:
            out[name] = base
        else:
            safe = name.strip("/").replace("/", "_") or "topic"
            out[name] = base.with_name(f"{base.stem}.{safe}{base.suffix}")
    return out


def _evo_arrays(res: Any, errors: Any) -> dict[str, Any]:
    """The arrays evo_ape puts in its result (``np_arrays``), as evo_res reads them."""
    import numpy as np

    t = res.reference.t.astype(np.float64) * 1e-9

    def travelled(pos: Any) -> Any:
        steps = np.linalg.norm(np.diff(pos, axis=0), axis=1)
        return np.concatenate([[0.0], np.cumsum(steps)])

    arrays = {
        "error_array": np.asarray(errors, dtype=np.float64),
        "timestamps": t,
        "seconds_from_start": t - t[0] if len(t) else t,
        "distances_from_start": travelled(res.reference.position),
        "distances": travelled(res.other.position),
    }
    if res.alignment.mode != "none":
        m = np.eye(4)
        m[:3, :3] = res.alignment.scale * res.alignment.rotation
        m[:3, 3] = res.alignment.translation
        arrays["alignment_transformation_sim3"] = m
    return arrays


def _save_results_zip(path: Path, result: Any, doc: dict[str, Any], relation: str) -> bytes:
    """evo's --save_results layout (stats.json, info.json and the .npy arrays evo_res reads)
    plus uwval.json and errors.csv."""
    import io
    import zipfile

    import numpy as np

    from uwval.comparison.engine import APE_RELATIONS, ape_errors
    from uwval.comparison.stats import norm_stats

    res = result.vehicle
    errors = ape_errors(res.reference, res.other, relation)
    ape = res.stats.get("ape") or {
        "pose_relation": relation,
        "unit": APE_RELATIONS.get(relation, ""),
        **norm_stats(errors),
    }
    stats = {k: ape[k] for k in ("rmse", "mean", "median", "std", "min", "max", "sse")}
    info = {
        "title": f"APE w.r.t. {ape['pose_relation']} ({ape['unit']})",
        "ref_name": result.sources[0] if result.sources else "",
        "est_name": result.sources[-1] if result.sources else "",
        "label": f"APE ({ape['unit']})",
        "alignment": res.alignment.mode,
    }
    import json

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("stats.json", json.dumps(stats, allow_nan=False))
        zf.writestr("info.json", json.dumps(info))
        for name, array in _evo_arrays(res, errors).items():
            npy = io.BytesIO()
            np.save(npy, array)
            zf.writestr(f"{name}.npy", npy.getvalue())
        zf.writestr("uwval.json", json.dumps(doc, indent=1, allow_nan=False))
        zf.writestr("errors.csv", errors_csv(res))
    return buf.getvalue()


def _short(stream: Any) -> str:
    """A stream named by its file's name (no folders) and topic: fits a figure's title."""
    name = Path(stream.source).name if stream.source else ""
    return f"{name} [{stream.topic}]" if stream.topic else name


def plot_targets(
    names: list[str], primary: str, save_plot: Path | None
) -> list[tuple[str, Path, Path]]:
    """Per topic: (name, trajectory PNG, error-over-time PNG) written by ``--plot``.

    Default ``uwval_<topic>_trajectory.png`` / ``uwval_<topic>_errors.png`` in the current
    folder; with ``--save_plot P.png`` (or .pdf, .svg, .jpg): P.png and P_errors.png (other
    topics: P.<topic>.png).
    """
    if save_plot is None:
        out = []
        for name in names:
            safe = name.strip("/").replace("/", "_") or "topic"
            out.append(
                (name, Path(f"uwval_{safe}_trajectory.png"), Path(f"uwval_{safe}_errors.png"))
            )
        return out
    base = save_plot
    if base.suffix.lower() not in PLOT_SUFFIXES:  # evo's --save_plot takes these too
        base = base.with_name(base.name + ".png")
    ext = base.suffix
    return [
        (name, path, Path(f"{path.with_suffix('')}_errors{ext}"))
        for name, path in _label_paths(base, names, primary).items()
    ]


#: Figure formats --save_plot writes as named (matplotlib's); any other name gets ``.png``.
PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


def extra_plot_targets(errors_png: Path) -> tuple[Path, Path]:
    """The error histogram and the error-coloured trajectory written beside a topic's
    error-over-time figure ``..._errors.EXT``: ``..._histogram.EXT``, ``..._errormap.EXT``."""
    ext = errors_png.suffix
    stem = errors_png.name.removesuffix(f"_errors{ext}")
    return (
        errors_png.with_name(f"{stem}_histogram{ext}"),
        errors_png.with_name(f"{stem}_errormap{ext}"),
    )


def _plot(result: Any, save_plot: Path | None) -> list[Path]:
    """--plot: per topic the trajectory, error-over-time, error-histogram and
    error-coloured trajectory figures as PNG files."""
    try:
        from uwval.reports.plots import (
            error_histogram_figure,
            timeseries_figure,
            trajectory_error_figure,
            trajectory_figure,
        )
    except ImportError as exc:  # matplotlib missing
        raise ConfigError(f"--plot needs matplotlib ({exc})") from None
    written = []
    for name, traj, errs in plot_targets(list(result.results), result.primary, save_plot):
        res = result.results[name]
        title = f"{name}: {_short(res.other)} vs {_short(res.reference)}"
        hist, errmap = extra_plot_targets(errs)
        targets = (
            (trajectory_figure, traj),
            (timeseries_figure, errs),
            (error_histogram_figure, hist),
            (trajectory_error_figure, errmap),
        )
        for make, target in targets:
            fig = make(res, title)
            try:
                target.parent.mkdir(parents=True, exist_ok=True)
                fig.savefig(target, dpi=100)
            except OSError as exc:
                raise ConfigError(
                    f"{target}: cannot write the plot: {exc.strerror or exc}"
                ) from None
            written.append(target)
    return written


def _interactive(result: Any, path: Path) -> Path:
    """--html: the interactive page (zoom/pan on errors and trajectory) of every topic."""
    from uwval.reports.interactive import write_interactive

    names = " vs ".join(Path(s).name for s in result.sources) if result.sources else ""
    try:
        return write_interactive(result.results, path, "uwval compare", names)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write the HTML page: {exc.strerror or exc}") from None


def run_compare(
    log_a: Path, log_b: Path | None = None, *, config: Path | None = None, **given: Any
) -> None:
    """What ``uwval compare`` does: ``given`` holds the options the user gave (keywords of
    :func:`_run_compare`); the project file (``--config``, or ``./uwval.toml``) fills the
    others (:mod:`uwval.config`)."""
    from uwval.config import load_config, merged_options

    opts = merged_options(given, load_config(config))
    evo_flags = any(given.get(k) for k in ("evo_align", "correct_scale", "align_origin"))
    if evo_flags and "align" not in given:  # the project file's align steps back
        opts.pop("align", None)
    if "offset" in opts:
        opts["offset"] = str(opts["offset"])
    else:  # no offset given: a log's recorded clock relation may supply it
        opts["recorded_clock"] = True
    if "max_diff" in given and "sync" not in opts:
        # evo associates by nearest stamp within --t_max_diff; a max diff given without a
        # sync method means that association (under interp it would be silently unused)
        opts["sync"] = "nearest"
    _run_compare(log_a, log_b, **opts)


def _run_compare(
    log_a: Path,
    log_b: Path | None = None,
    *,
    pairs: Any = None,
    gazebo_topic: str | None = None,
    unity_topic: str | None = None,
    fmt: str | None = None,
    frame: str | None = None,
    sync: str = "interp",
    max_gap: float | None = None,
    max_diff: float = 0.01,
    offset: str = "0",
    recorded_clock: bool = False,
    max_offset: float | None = None,
    drift: str = "off",
    align: str = "none",
    evo_align: bool = False,
    correct_scale: bool = False,
    align_origin: bool = False,
    n_to_align: int = -1,
    pose_relation: str | None = None,
    verbose: bool = False,
    plot: bool = False,
    save_plot: Path | None = None,
    save_errors: Path | None = None,
    save_results: Path | None = None,
    html: Path | None = None,
    as_json: bool = False,
    output: Path | None = None,
) -> None:
    """What ``uwval compare`` does for one log or one pair of files: compare, print, save."""
    from uwval.cli.notes import warnings_as_notes
    from uwval.comparison.logs import compare_logs

    mode = _align_mode(align, evo_align, correct_scale, align_origin)
    if html is not None and html.suffix.lower() not in (".html", ".htm"):
        raise ConfigError(f"--html {html}: the page's name must end in .html")
    if n_to_align != -1 and n_to_align < 1:
        raise ConfigError(f"--n_to_align must be >= 1 (or -1 for all), got {n_to_align}")
    if pose_relation is not None:
        from uwval.comparison.engine import APE_RELATIONS

        if pose_relation not in APE_RELATIONS:
            raise ConfigError(
                f"--pose_relation {pose_relation!r}: choose one of {', '.join(APE_RELATIONS)}"
            )
    with warnings_as_notes():
        result = compare_logs(
            log_a,
            log_b,
            gazebo_topic=gazebo_topic,
            unity_topic=unity_topic,
            fmt=fmt,
            frame=frame,
            sync=sync,
            max_gap=max_gap,
            max_diff=max_diff,
            offset=_parse_offset(offset),
            max_offset=max_offset,
            drift=drift,
            align=mode,
            n_to_align=n_to_align,
            pairs=pairs,
            recorded_clock=recorded_clock,
        )
    if pose_relation is not None:
        from uwval.comparison.engine import ape_statistics

        for res in result.results.values():
            res.stats["ape"] = ape_statistics(res.reference, res.other, pose_relation)
    # the whole JSON document only when something is written from it (a table needs none)
    wants_doc = as_json or output is not None or save_results is not None
    doc = result.to_json() if wants_doc else {}
    text = ""
    if wants_doc:
        import json  # only a JSON document needs it (~1.4 ms of a compare's start-up)

        text = json.dumps(doc, indent=1, allow_nan=False)
    if output is not None:
        _write_output(output, text + "\n", "the JSON result")
    if save_results is not None:
        if save_results.suffix.lower() == ".zip":
            data: bytes | str = _save_results_zip(
                save_results, result, doc, pose_relation or "trans_part"
            )
        else:
            data = text + "\n"
        _write_output(save_results, data, "the results")
    saved: list[Path] = [save_results] if save_results is not None else []
    if save_errors is not None:
        for name, path in _label_paths(save_errors, list(result.results), result.primary).items():
            _write_output(path, errors_csv(result.results[name]), "the per-sample errors")
            saved.append(path)
    if plot or save_plot is not None:
        saved += _plot(result, save_plot)
    if html is not None:
        saved.append(_interactive(result, html))
    if as_json:
        sys.stdout.write(text + "\n")
        for path in saved:  # stdout holds the JSON alone
            sys.stderr.write(f"wrote {path}\n")
        return
    for name, res in result.results.items():
        _print_table(res.to_json(), f"{name}: {res.other.describe()} vs {res.reference.describe()}")
        if verbose and res.alignment.mode != "none":
            import numpy as np

            al = res.alignment
            sys.stdout.write(
                f"alignment {al.mode}: scale {al.scale:.9g}, translation (m) "
                f"{np.array2string(al.translation, precision=9)}, rotation\n"
                f"{np.array2string(al.rotation, precision=9)}\n"
            )
    for path in saved:
        sys.stdout.write(f"wrote {path}\n")


@dataclass(frozen=True)
class CompareOption:
    """One option of ``uwval compare``: the one source of both command-line parsers.

    The typer command (:mod:`uwval.cli.compare_cmd`, for ``--help``, usage errors and
    ``--batch``) is built from :data:`COMPARE_OPTIONS`, and so is the light parser of
    :func:`fast_compare`; an option exists in both or in neither.
    """

    dest: str  # keyword of run_compare / the typer command
    flags: tuple[str, ...]
    kind: Any  # str, float, int, bool (a flag), Path, or list[str] (a repeatable option)
    default: Any
    help: str
    fast: bool = True  # False: only typer handles it (the fast path declines, runs nothing)


FRAME_HELP = (
    "Convention of the second (Unity) stream: unity-flu, unity-enu, ned, enu or auto "
    "(default: from the log's frame_id; enu for TUM files)"
)

#: Every option of ``uwval compare``, in ``--help`` order.
COMPARE_OPTIONS: tuple[CompareOption, ...] = (
    CompareOption(
        "gazebo_topic",
        ("--gazebo-topic",),
        str,
        None,
        "Reference topic (a TF topic's transform: /tf#CHILD; `uwval inspect` lists them)",
    ),
    CompareOption(
        "unity_topic", ("--unity-topic",), str, None, "Other (Unity) topic (/tf#CHILD too)"
    ),
    CompareOption(
        "fmt",
        ("--format",),
        str,
        None,
        "Input format: tum, or a log format read by uwval.io (default: by suffix)",
    ),
    CompareOption("frame", ("--frame",), str, None, FRAME_HELP),
    CompareOption(
        "sync",
        ("--sync",),
        str,
        "interp",
        "interp (lerp+slerp at reference stamps) or nearest (evo's association: "
        "--sync nearest --max-diff 0.01 gives evo_ape's numbers)",
    ),
    CompareOption(
        "max_gap",
        ("--max-gap",),
        float,
        None,
        "interp: mask samples in gaps longer than this (s; default 5 periods)",
    ),
    CompareOption(
        "max_diff",
        ("--max-diff", "--t_max_diff", "--t-max-diff"),
        float,
        0.01,
        "nearest: max stamp difference (s; --t_max_diff is evo's spelling). Given without "
        "--sync, it means --sync nearest (evo's association)",
    ),
    CompareOption(
        "offset",
        ("--offset", "--t_offset", "--t-offset"),
        str,
        "0",
        "Clock offset added to the second stream's stamps (s), or 'auto' to estimate it "
        "(--t_offset is evo's spelling, same sign)",
    ),
    CompareOption("max_offset", ("--max-offset",), float, None, "Bound for --offset auto (s)"),
    CompareOption(
        "drift",
        ("--drift",),
        str,
        "off",
        "Clock drift of the second stream: auto fits it (ppm; applied stamps, else the "
        "lag's trend) and removes it; off leaves it (a long drifting run gets a warning)",
    ),
    CompareOption(
        "align",
        ("--align",),
        str,
        "none",
        "none, se3, sim3 (Umeyama), origin or scale (evo's -s alone); --align with no "
        "value (last, or before another option) is evo's flag: se3",
    ),
    CompareOption(
        "evo_align",
        ("-a",),
        bool,
        False,
        "evo's -a: SE(3) Umeyama alignment (= --align se3; -as: Sim(3), = --align sim3)",
    ),
    CompareOption(
        "correct_scale",
        ("-s", "--correct_scale", "--correct-scale"),
        bool,
        False,
        "evo's -s: correct the scale (with -a: Sim(3); alone: scale only)",
    ),
    CompareOption(
        "align_origin",
        ("--align_origin", "--align-origin"),
        bool,
        False,
        "evo's --align_origin: = --align origin",
    ),
    CompareOption(
        "n_to_align",
        ("--n_to_align", "--n-to-align"),
        int,
        -1,
        "Fit the alignment on the first N aligned samples only, apply it to all (-1: all)",
    ),
    CompareOption(
        "pose_relation",
        ("-r", "--pose_relation", "--pose-relation"),
        str,
        None,
        "Also give evo_ape's statistics of this pose relation: trans_part, rot_part, full, "
        "angle_deg, angle_rad or point_distance (printed, and under 'ape' in the JSON)",
    ),
    CompareOption(
        "verbose",
        ("-v", "--verbose"),
        bool,
        False,
        "evo's -v: also print the alignment (rotation, translation, scale)",
    ),
    CompareOption(
        "plot",
        ("--plot",),
        bool,
        False,
        "Write PNG files (no window opens): trajectory, error over time, error histograms "
        "and the trajectory coloured by the position error (evo_ape --plot_mode xy): to "
        "--save_plot, else uwval_<topic>_{trajectory,errors,histogram,errormap}.png here",
    ),
    CompareOption(
        "save_plot",
        ("--save_plot", "--save-plot"),
        Path,
        None,
        "PNG path of the trajectory plot (the others go beside it: *_errors.png, "
        "*_histogram.png, *_errormap.png); implies --plot",
    ),
    CompareOption(
        "save_errors",
        ("--save-errors", "--save_errors"),
        Path,
        None,
        "Write the per-sample signed errors as CSV: one row per aligned sample (stamp, "
        "x y z m, roll pitch yaw deg, position norm m, rotation angle deg)",
    ),
    CompareOption(
        "save_results",
        ("--save_results", "--save-results"),
        Path,
        None,
        "evo's --save_results: a .zip holds stats.json and info.json (evo's keys), "
        "uwval.json (the full result) and errors.csv; any other suffix: the JSON result",
    ),
    CompareOption(
        "html",
        ("--html",),
        Path,
        None,
        "Write an interactive, self-contained HTML page (no network): errors over time and "
        "the trajectory with wheel zoom and drag pan",
    ),
    CompareOption("as_json", ("--json",), bool, False, "Print the JSON result"),
    CompareOption(
        "config",
        ("--config",),
        Path,
        None,
        "Project file naming pairs, frames and option defaults (default: ./uwval.toml when "
        "present; options given here win)",
    ),
    CompareOption(
        "output",
        ("-o", "--output"),
        Path,
        None,
        "Also write the JSON result here (with --batch: the results directory)",
    ),
    CompareOption(
        "batch",
        ("--batch",),
        bool,
        False,
        "LOG_A is an experiment directory or manifest: compare every log into one results table",
        fast=False,
    ),
    CompareOption(
        "executor",
        ("--executor",),
        str,
        "local",
        "--batch: local (process pool), dask or inline",
        fast=False,
    ),
    CompareOption("workers", ("--workers",), int, None, "--batch: worker processes", fast=False),
    CompareOption(
        "scheduler", ("--scheduler",), str, None, "--batch: Dask scheduler address", fast=False
    ),
    CompareOption(
        "allow_protocol",
        ("--allow-protocol",),
        list[str],
        None,
        "--batch: fetch manifest logs by this remote protocol (s3, gs, http...; repeatable; "
        "also UWVAL_ALLOW_PROTOCOLS=s3,gs). Without it only local paths are read",
        fast=False,
    ),
)

#: What ``fast_compare`` understands, derived from :data:`COMPARE_OPTIONS`:
#: option flag -> (keyword of run_compare, kind).
_FAST_OPTIONS: dict[str, tuple[str, type]] = {
    flag: (o.dest, o.kind) for o in COMPARE_OPTIONS if o.fast for flag in o.flags
}
_PLAIN_FLOAT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def _bare_align(argv: list[str]) -> list[str]:
    """evo's ``--align`` is a flag (SE(3)); uwval's takes a value. ``--align`` last or
    followed by another option is evo's flag: rewritten to ``-a``."""
    out = list(argv)
    for i, arg in enumerate(out):
        if arg == "--align" and (i + 1 == len(out) or out[i + 1].startswith("-")):
            out[i] = "-a"
    return out


def _expand_short_flags(argv: list[str]) -> list[str]:
    """``-as`` -> ``-a -s``, ``-va`` -> ``-v -a`` (click's clustering of short flags), when
    every letter is a known short flag of :data:`COMPARE_OPTIONS` (anything else is left)."""
    out: list[str] = []
    for arg in argv:
        letters = arg[1:]
        if (
            arg.startswith("-")
            and not arg.startswith("--")
            and len(letters) > 1
            and arg not in _FAST_OPTIONS
            and all(_FAST_OPTIONS.get("-" + c, ("", None))[1] is bool for c in letters)
        ):
            out.extend("-" + c for c in letters)
        else:
            out.append(arg)
    return out


def fast_compare(argv: list[str]) -> bool:
    """Run ``uwval compare`` from the arguments after ``compare``, if they are plain.

    The same :func:`run_compare` runs, so output and errors are identical; only the
    command-line parsing is lighter. Returns False without doing anything when an argument
    is not a plain value of a known option (help, a typo, a repeated option, a number typer
    might read differently...): the caller then lets typer parse, which owns usage errors.
    """
    kwargs: dict[str, Any] = {}
    positional: list[str] = []
    args = iter(_expand_short_flags(_bare_align(argv)))
    for arg in args:
        if arg.startswith("-") and not _PLAIN_FLOAT.fullmatch(arg):
            name, has_value, value = arg.partition("=")
            spec = _FAST_OPTIONS.get(name)
            if spec is None or spec[0] in kwargs:
                return False
            dest, kind = spec
            if kind is bool:  # a flag: no value
                if has_value:
                    return False
                kwargs[dest] = True
                continue
            if not has_value:
                value = next(args, "")
            if not value:
                return False
            if kind is float:
                if not _PLAIN_FLOAT.fullmatch(value):
                    return False
                kwargs[dest] = float(value)
            elif kind is int:
                if not re.fullmatch(r"[-+]?\d+", value):
                    return False
                kwargs[dest] = int(value)
            elif kind is str or kind is Path:
                kwargs[dest] = kind(value)
            else:  # a kind the light parser does not convert: typer's job
                return False
        else:
            positional.append(arg)
    if len(positional) not in (1, 2):
        return False
    run_compare(
        Path(positional[0]), Path(positional[1]) if len(positional) == 2 else None, **kwargs
    )
    return True
