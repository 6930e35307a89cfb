"""A run whose workers, run directory, model or Ray cluster cannot be used stops before any trial, in one line."""
import json
import subprocess
import sys
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from sagp_batched.config import load_config
from sagp_batched.preflight import PreflightError, check_rater, preflight

REPO = Path(__file__).resolve().parent.parent
# Port 9 (discard) is closed on test machines: connections to it are refused at once.
CLOSED_PORT = 9


def _batch(tmp_path, ycb_dir, *flags, out=None):
    out = out or tmp_path / "run"
    command = [sys.executable, "-m", "runners.batch", "--profile", "ci", "--objects", "005_tomato_soup_can",
               "--tasks", "t1", "--n-trials", "1", "--methods", "go", "--objects-dir", str(ycb_dir),
               "--out", str(out), "--no-progress", *flags]
    return subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=300), out


def _the_one_error_line(result, out) -> str:
    """The run exited 2 with one ``error:`` line and wrote no trials (nor its run directory)."""
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip() and not line.startswith("pybullet build time")]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert not (out / "trials.jsonl").exists()
    assert not out.exists()
    return lines[0]


@pytest.fixture
def models_endpoint():
    """An OpenAI-compatible base URL on loopback whose /models lists one model, 'served-vl'."""

    class Models(BaseHTTPRequestHandler):
        def do_GET(self):
            body = json.dumps({"object": "list", "data": [{"id": "served-vl", "object": "model"}]}).encode()
            self.send_response(200 if self.path == "/v1/models" else 404)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Models)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}/v1"
    server.shutdown()
    server.server_close()


def test_a_usable_run_passes_preflight_and_it_leaves_no_run_directory(tmp_path):
    out = tmp_path / "new" / "run"
    preflight(load_config("ci", overrides={"run": {"out": str(out)}}))
    assert not (tmp_path / "new").exists()


def test_zero_workers_stop_the_run_before_any_trial(tmp_path, ycb_dir):
    line = _the_one_error_line(*_batch(tmp_path, ycb_dir, "--workers", "0"))
    assert "--workers" in line and "0" in line


def test_a_run_directory_under_a_file_stops_the_run_with_the_os_reason(tmp_path, ycb_dir):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    result, out = _batch(tmp_path, ycb_dir, out=blocker / "run")
    line = _the_one_error_line(result, out)
    assert str(blocker / "run") in line and "Not a directory" in line


def test_a_missing_transformers_model_is_named_before_any_trial(tmp_path, ycb_dir):
    model = tmp_path / "no_such_model"
    line = _the_one_error_line(*_batch(tmp_path, ycb_dir, "--rater", "transformers", "--model", str(model)))
    assert str(model) in line


def test_an_openai_endpoint_that_refuses_connections_stops_the_run(tmp_path, ycb_dir):
    endpoint = f"http://127.0.0.1:{CLOSED_PORT}/v1"
    line = _the_one_error_line(*_batch(tmp_path, ycb_dir, "--rater", "openai", "--endpoint", endpoint, "--model", "served-vl"))
    assert f"{endpoint}/models" in line


def test_an_openai_endpoint_that_does_not_serve_the_model_names_it(tmp_path, ycb_dir, models_endpoint):
    line = _the_one_error_line(*_batch(tmp_path, ycb_dir, "--rater", "openai", "--endpoint", models_endpoint,
                                       "--model", "absent-vl"))
    assert "'absent-vl'" in line and "served-vl" in line


def test_an_openai_endpoint_that_serves_the_model_passes(models_endpoint):
    rating = load_config("ci", overrides={"rating": {"backend": "openai", "endpoint": models_endpoint, "model": "served-vl"}}).rating
    check_rater(rating)
    with pytest.raises(PreflightError, match="absent-vl"):
        check_rater(load_config("ci", overrides={"rating": {"backend": "openai", "endpoint": models_endpoint,
                                                            "model": "absent-vl"}}).rating)


def test_an_unreachable_ray_address_stops_the_run_without_starting_ray(tmp_path, ycb_dir):
    address = f"ray://127.0.0.1:{CLOSED_PORT}"
    line = _the_one_error_line(*_batch(tmp_path, ycb_dir, "--backend", "ray", "--address", address))
    assert address in line
