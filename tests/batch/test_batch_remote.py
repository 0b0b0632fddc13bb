"""Issue 14, security: ``compare --batch`` reads local paths; a manifest alone never makes
uwval fetch a URL (ftp, http, s3...): the user must allow the protocol themselves."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import pytest
from cli_runner import run_uwval

from uwval.batch import BatchItem, allowed_protocols, compare_batch, compare_item, items_from
from uwval.errors import ConfigError


@pytest.fixture
def listener() -> socket.socket:
    """A real TCP listener on loopback: the test checks that nobody connects to it."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(4)
    srv.settimeout(0.5)
    yield srv
    srv.close()


def _nobody_connected(srv: socket.socket) -> bool:
    try:
        conn, _ = srv.accept()
    except TimeoutError:
        return True
    conn.close()
    return False


def _manifest(tmp_path: Path, logs: list[str]) -> Path:
    runs = [{"name": f"r{i}", "log": log, "factors": {}} for i, log in enumerate(logs)]
    m = tmp_path / "manifest.json"
    m.write_text(json.dumps({"runs": runs}))
    return m


@pytest.mark.parametrize("scheme", ["ftp", "http", "simplecache::ftp", "FTP"])
def test_manifest_urls_are_refused_without_an_allow_list(
    tmp_path: Path, listener: socket.socket, scheme: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("UWVAL_ALLOW_PROTOCOLS", raising=False)
    port = listener.getsockname()[1]
    m = _manifest(tmp_path, [f"{scheme}://127.0.0.1:{port}/run.mcap"])
    with pytest.raises(ConfigError, match=r"run 0 \(r0\).*is remote.*--allow-protocol"):
        compare_batch(m, executor="inline", progress=False)
    assert _nobody_connected(listener)


def test_cli_refuses_a_manifest_url_and_connects_nowhere(
    tmp_path: Path, listener: socket.socket
) -> None:
    port = listener.getsockname()[1]
    m = _manifest(tmp_path, [f"ftp://127.0.0.1:{port}/run.mcap"])
    p = run_uwval("compare", "--batch", m, "--executor", "inline")
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert "is remote (ftp)" in p.stderr
    assert _nobody_connected(listener)


def test_an_allowed_protocol_is_not_enough_for_another_one(
    tmp_path: Path, listener: socket.socket
) -> None:
    port = listener.getsockname()[1]
    m = _manifest(tmp_path, [f"http://127.0.0.1:{port}/run.mcap"])
    with pytest.raises(ConfigError, match="is remote"):
        items_from(m, allow=["s3", "memory"])
    assert _nobody_connected(listener)


def test_compare_item_checks_the_allow_list_itself(listener: socket.socket) -> None:
    port = listener.getsockname()[1]
    with pytest.raises(ConfigError, match="is remote"):
        compare_item(BatchItem("x", f"ftp://127.0.0.1:{port}/a.mcap"))
    assert _nobody_connected(listener)


def test_allow_list_from_the_command_line_and_the_environment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("UWVAL_ALLOW_PROTOCOLS", " s3, GS ,")
    assert allowed_protocols(["memory://"]) == {"s3", "gs", "memory"}
    m = _manifest(tmp_path, ["s3://bucket/a.mcap", "local.mcap"])
    items = items_from(m)
    assert items[0].log == "s3://bucket/a.mcap" and items[1].log == str(tmp_path / "local.mcap")


def test_local_paths_need_no_allow_list(tmp_path: Path) -> None:
    m = _manifest(tmp_path, ["runs/a.mcap", str(tmp_path / "b.mcap"), "file:/x.mcap"])
    assert [i.log for i in items_from(m)][:2] == [
        str(tmp_path / "runs" / "a.mcap"),
        str(tmp_path / "b.mcap"),
    ]
