"""What ``uwval compare`` writes besides its table: the JSON result, per-sample errors (CSV),
evo's ``--save_results`` zip, PNG plots and the interactive HTML page.

Each writer takes the typed :class:`uwval.comparison.logs.LogComparison`; a file that cannot
be written is a one-line :class:`ConfigError` naming it.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from uwval.comparison.engine import ComparisonResult, ape_errors
from uwval.comparison.logs import APE_STATISTICS, ApeStatistics, LogComparison
from uwval.errors import ConfigError


def write_output(path: Path, data: bytes | str, what: str) -> None:
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


def label_paths(base: Path, names: list[str], primary: str) -> dict[str, Path]:
    """One output path per topic: ``base`` for the primary topic, base.<name>.suffix else."""
    out = {}
    for name in names:
        if name == primary:
            out[name] = base
        else:
            safe = name.strip("/").replace("/", "_") or "topic"
            out[name] = base.with_name(f"{base.stem}.{safe}{base.suffix}")
    return out


def not_evo_comparable(result: ComparisonResult) -> str | None:
    """Why evo_ape would give other numbers for this comparison, or None when it would give
    the same: evo associates by nearest stamp, converts no frame, estimates no offset."""
    stats = result.stats
    if stats["sync"]["method"] != "nearest":
        return f"sync {stats['sync']['method']}: the other stream was interpolated"
    frame = stats["frame"]
    if frame["configured"] != "enu" or frame["reference"] != "enu":
        return f"frame {frame['configured']}: the other stream was converted to ENU"
    if stats["offset"]["source"] == "auto":
        return "offset auto: the clock offset was estimated"
    return None


def _evo_arrays(res: ComparisonResult, errors: Any) -> dict[str, Any]:
    """The arrays evo_ape puts in its result (``np_arrays``), as evo_res reads them."""
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


def save_results_zip(result: LogComparison, relation: str) -> tuple[bytes, str | None]:
    """``--save_results X.zip``: the zip's bytes, and why it is not an evo result (or None).

    When evo_ape would give the same numbers the zip has evo's layout (stats.json and
    info.json with evo's keys, the .npy arrays evo_res reads) plus uwval.json and errors.csv.
    Otherwise evo's two files are left out, so that evo_res refuses the zip instead of
    mixing numbers it did not compute with its own (the statistics go to uwval_stats.json).
    """
    res = result.vehicle
    ape = result.ape.get(result.primary) or ApeStatistics.of(res, relation)
    errors = ape_errors(res.reference, res.other, ape.relation)
    stats = {k: getattr(ape, k) for k in APE_STATISTICS}
    info = {
        "title": f"APE w.r.t. {ape.relation} ({ape.unit})",
        "ref_name": result.sources[0] if result.sources else "",
        "est_name": result.sources[-1] if result.sources else "",
        "label": f"APE ({ape.unit})",
        "alignment": res.alignment.mode,
    }
    reason = not_evo_comparable(res)
    extra = {
        "uwval.json": json.dumps(result.to_json(), indent=1, allow_nan=False),
        "errors.csv": errors_csv(res),
    }
    return evo_zip(stats, info, reason, _evo_arrays(res, errors), extra), reason


def evo_zip(
    stats: dict[str, Any],
    info: dict[str, Any],
    reason: str | None,
    arrays: dict[str, Any],
    extra: dict[str, str],
) -> bytes:
    """A --save_results zip: evo's layout (stats.json, info.json, the .npy arrays evo_res
    reads) when ``reason`` is None, else the statistics in uwval_stats.json with the reason,
    so that evo_res refuses the zip; ``extra`` files (name -> text) are added as they are."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        if reason is None:
            zf.writestr("stats.json", json.dumps(stats, allow_nan=False))
            zf.writestr("info.json", json.dumps(info))
        else:
            doc = {"not_an_evo_result": reason, "info": info, "stats": stats}
            zf.writestr("uwval_stats.json", json.dumps(doc, allow_nan=False))
        for name, array in arrays.items():
            npy = io.BytesIO()
            np.save(npy, np.asarray(array, dtype=np.float64))
            zf.writestr(f"{name}.npy", npy.getvalue())
        for name, text in extra.items():
            zf.writestr(name, text)
    return buf.getvalue()


def _short(stream: Any) -> str:
    """A stream named by its file's name (no folders) and topic: fits a figure's title."""
    name = Path(stream.source).name if stream.source else ""
    return f"{name} [{stream.topic}]" if stream.topic else name


#: Figure formats --save_plot writes as named (matplotlib's); any other name gets ``.png``.
PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


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
        for name, path in label_paths(base, names, primary).items()
    ]


def extra_plot_targets(errors_png: Path) -> tuple[Path, Path]:
    """The error histogram and the error-coloured trajectory written beside a topic's
    error-over-time figure ``..._errors.EXT``: ``..._histogram.EXT``, ``..._errormap.EXT``."""
    ext = errors_png.suffix
    stem = errors_png.name.removesuffix(f"_errors{ext}")
    return (
        errors_png.with_name(f"{stem}_histogram{ext}"),
        errors_png.with_name(f"{stem}_errormap{ext}"),
    )


def write_plots(result: LogComparison, save_plot: Path | None) -> list[Path]:
    """--plot: per topic the trajectory, error-over-time, error-histogram and
    error-coloured trajectory figures as image files; returns the paths written."""
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
        res: Any = result.results[name]  # the plots take any AlignedPair
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


def write_html(result: LogComparison, path: Path, how: str) -> Path:
    """--html: the interactive page (zoom/pan on errors and trajectory) of every topic;
    ``how`` (the sync and alignment used) goes into its subtitle."""
    from uwval.reports.interactive import write_interactive

    names = " vs ".join(Path(s).name for s in result.sources) if result.sources else ""
    subtitle = f"{names} ({how})" if names else how
    try:
        return write_interactive(result.results, path, "uwval compare", subtitle)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write the HTML page: {exc.strerror or exc}") from None
