"""Scale-out (issue 9): a small sweep (data/experiments/quick.toml, the default experiment at
2 levels, 8 runs: these tests are about executors, not the study) on Dask == the local pool."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

from uwval.batch import Executor, compare_batch, items_from
from uwval.bridge.experiment import SimulateOptions, run_experiment
from uwval.errors import ConfigError
from uwval.resources import data_path

HAS_DASK = importlib.util.find_spec("distributed") is not None


def sweep(out: Path, executor: str, workers: int | None = None, batched: bool = False) -> dict:  # type: ignore[type-arg]
    """The quick experiment (8 runs) simulated into ``out``; its manifest."""
    opts = SimulateOptions(
        output=out,
        experiment="quick",
        executor=Executor(executor),
        workers=workers,
        batch_physics=batched,
    )
    return run_experiment(opts).manifest


def _numbers(runs: list[dict]) -> dict[str, dict]:  # type: ignore[type-arg]
    """Every run's comparison numbers, keyed by run name (wall times left out)."""
    out = {}
    for r in runs:
        c = r["comparison"]
        out[r["name"]] = {
            "factors": r["factors"],
            "axes": c["axes"],
            "pen": c["position_error_norm"],
            "n": c["n_samples"],
        }
    return out


@pytest.mark.skipif(not HAS_DASK, reason="dask.distributed not installed")
def test_dask_sweep_and_batch_identical_to_local(tmp_path: Path) -> None:
    local = sweep(tmp_path / "local", "local", workers=2)
    dask = sweep(tmp_path / "dask", "dask", workers=2)
    assert not local["failed"] and not dask["failed"]
    assert [r["name"] for r in dask["runs"]] == [r["name"] for r in local["runs"]]
    assert len(local["runs"]) == 8
    b_local = compare_batch(tmp_path / "local", executor="local", workers=2, progress=False)
    b_dask = compare_batch(tmp_path / "dask", executor="dask", workers=2, progress=False)
    assert _numbers(b_dask.runs) == _numbers(b_local.runs)
    df_l = b_local.table.to_dataframe().sort_values(["run", "topic", "axis", "metric"])
    df_d = b_dask.table.to_dataframe().sort_values(["run", "topic", "axis", "metric"])
    assert df_l["value"].fillna(-1).tolist() == df_d["value"].fillna(-1).tolist()


def test_batch_reports_failing_log_and_completes_others(tmp_path: Path) -> None:
    m = sweep(tmp_path / "sweep", "inline")
    bad = tmp_path / "sweep" / m["runs"][3]["log"]
    bad.write_bytes(b"not an mcap at all")
    batch = compare_batch(tmp_path / "sweep", executor="local", workers=2, progress=False)
    assert len(batch.runs) == 7
    assert len(batch.failed) == 1
    assert batch.failed[0]["name"] == m["runs"][3]["name"]
    assert str(bad.name) in batch.failed[0]["error"]
    written = batch.save(tmp_path / "results")
    names = {p.name for p in written}
    assert "comparisons.json" in names
    saved = json.loads((tmp_path / "results" / "comparisons.json").read_text())
    assert saved["failed"][0]["name"] == m["runs"][3]["name"]


def test_items_from_errors_name_the_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such manifest"):
        items_from(tmp_path / "missing")
    (tmp_path / "manifest.json").write_text("{broken")
    with pytest.raises(ConfigError, match=r"manifest.json: not valid JSON: line 1"):
        items_from(tmp_path)


def test_simulate_experiment_cli_writes_manifest(tmp_path: Path) -> None:
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "uwval",
            "simulate",
            str(data_path("experiments", "quick.toml")),
            "-o",
            str(tmp_path / "exp"),
            "--executor",
            "local",
            "--workers",
            "2",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        stdin=subprocess.DEVNULL,
    )
    assert res.returncode == 0, res.stderr
    manifest = json.loads((tmp_path / "exp" / "manifest.json").read_text())
    assert len(manifest["runs"]) == 8
    levels = {
        (r["factors"]["force"], r["factors"]["torque"], r["factors"]["current"])
        for r in manifest["runs"]
    }
    assert len(levels) == 8  # full factorial: 2 x 2 x 2 distinct combinations
    for r in manifest["runs"]:
        assert (tmp_path / "exp" / r["log"]).is_file()
        assert r["bridge"]["sent"] > 0


def test_logs_on_an_object_store_url_are_fetched(tmp_path: Path) -> None:
    fsspec = pytest.importorskip("fsspec")
    m = sweep(tmp_path / "sweep", "inline")
    fs = fsspec.filesystem("memory")
    runs = []
    for r in m["runs"][:2]:
        url = f"memory://bucket/{Path(r['log']).name}"
        fs.pipe(url, (tmp_path / "sweep" / r["log"]).read_bytes())
        runs.append({**r, "log": url})
    runs.append({"name": "gone", "log": "memory://bucket/missing.mcap", "factors": {}})
    (tmp_path / "remote.json").write_text(json.dumps({"runs": runs}))
    batch = compare_batch(
        tmp_path / "remote.json", executor="inline", progress=False, allow_protocols=["memory"]
    )
    local = compare_batch(tmp_path / "sweep", executor="inline", progress=False)
    assert [r["name"] for r in batch.runs] == [r["name"] for r in m["runs"][:2]]
    assert _numbers(batch.runs) == {
        k: v for k, v in _numbers(local.runs).items() if k in {r["name"] for r in batch.runs}
    }
    assert batch.failed[0]["name"] == "gone"
    assert "missing.mcap: no such object" in batch.failed[0]["error"]


def test_compare_batch_cli(tmp_path: Path) -> None:
    sweep(tmp_path / "sweep", "inline")
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "uwval",
            "compare",
            "--batch",
            str(tmp_path / "sweep"),
            "-o",
            str(tmp_path / "res"),
            "--workers",
            "2",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        stdin=subprocess.DEVNULL,
    )
    assert res.returncode == 0, res.stderr
    assert "compared 8 logs" in res.stdout
    import pandas as pd

    df = pd.read_csv(tmp_path / "res" / "results.csv")
    assert set(df["run"]) == {f.stem for f in (tmp_path / "sweep" / "runs").glob("*.mcap")}
    assert {"force", "torque", "current"} <= set(df.columns)
    mae_x = df[(df["axis"] == "x") & (df["metric"] == "mae")]
    assert len(mae_x) == 16  # 8 runs x (vehicle, camera)


def test_batched_physics_sweep_matches_per_run_physics(tmp_path: Path) -> None:
    per_run = sweep(tmp_path / "a", "inline")
    batched = sweep(tmp_path / "b", "local", workers=2, batched=True)
    assert [r["name"] for r in batched["runs"]] == [r["name"] for r in per_run["runs"]]
    a = compare_batch(tmp_path / "a", executor="inline", progress=False)
    b = compare_batch(tmp_path / "b", executor="inline", progress=False)
    from uwval.io import read_stream

    for ra, rb in zip(per_run["runs"], batched["runs"], strict=True):
        ga = read_stream(tmp_path / "a" / ra["log"], "/gazebo/model_rov_pose")
        gb = read_stream(tmp_path / "b" / rb["log"], "/gazebo/model_rov_pose")
        assert (ga.t == gb.t).all()
        assert abs(ga.position - gb.position).max() < 1e-9  # equal to rounding
    na, nb = _numbers(a.runs), _numbers(b.runs)
    for name in na:
        assert nb[name]["axes"]["x"]["mae"] == pytest.approx(
            na[name]["axes"]["x"]["mae"], rel=1e-6, abs=1e-12
        )


@pytest.mark.skipif(not HAS_DASK, reason="dask.distributed not installed")
@pytest.mark.parametrize("executor", ["local", "dask"])
def test_worker_killed_mid_sweep_every_run_present_once(tmp_path: Path, executor: str) -> None:
    import cloudpickle
    import executor_tasks

    from uwval.batch.executors import run_tasks
    from uwval.bridge.experiment import RunJob, log_path_for
    from uwval.simulator import load_experiment

    cloudpickle.register_pickle_by_value(executor_tasks)
    specs = load_experiment(data_path("experiments", "quick.toml")).runs()
    victim = specs[3].name
    jobs = [
        (RunJob(s, str(log_path_for(tmp_path, s.name, "mcap"))), victim, str(tmp_path))
        for s in specs
    ]
    out = run_tasks(
        executor_tasks.run_one_dying_once,
        jobs,
        [s.name for s in specs],
        executor=executor,
        workers=2,
        retries=2,
        progress=False,
    )
    assert (tmp_path / "killed").read_text() == victim  # a worker really died
    assert [o.key for o in out] == [s.name for s in specs]
    assert all(o.ok for o in out), [o.error for o in out if not o.ok]
    names = [o.value["name"] for o in out if o.value is not None]
    assert sorted(names) == sorted(s.name for s in specs)  # every run once
    logs = sorted((tmp_path / "runs").glob("*.mcap"))
    finished = [p for p in logs if not p.name.endswith(".partial.mcap")]
    assert len(finished) == len(specs)
    # the killed attempt's unfinished log, if the worker died after opening it, is kept
    # beside the retried run's log (nothing recorded is lost), never in its place
    leftovers = [p.name for p in logs if p.name.endswith(".partial.mcap")]
    assert leftovers in ([], [f"{victim}.partial.mcap"]), leftovers
