"""Captions against a loopback OpenAI-compatible mock server: the paper's prompt, frame rates, retries, cache, budget."""

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np
import pytest
from _datasets import base_parts, write_episode

from oscar_core.data.caption import SYSTEM_PROMPT, CaptionConfig, frame_indices
from oscar_core.data.engine import StageIncomplete, read_stage
from oscar_core.data.manifest import rows_from_parquet
from oscar_core.data.run import run_caption, run_ingest

pytest.importorskip("openai")


class MockVLM:
    """An OpenAI chat-completions endpoint on 127.0.0.1 that records requests and can fail the first ``fail`` ones."""

    def __init__(self):
        self.requests, self.fail, self.always_fail = [], 0, False
        mock = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *a):
                pass

            def do_POST(self):
                body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                mock.requests.append({"path": self.path, "body": body})
                if mock.always_fail or mock.fail > 0:
                    mock.fail -= 1
                    self.send_response(500)
                    self.send_header("retry-after-ms", "10")
                    self.send_header("Content-Type", "application/json")
                    self.end_headers()
                    self.wfile.write(b'{"error": {"message": "overloaded"}}')
                    return
                images = [p for p in body["messages"][1]["content"] if p["type"] == "image_url"]
                answer = {
                    "id": "c1",
                    "object": "chat.completion",
                    "created": 0,
                    "model": body["model"],
                    "choices": [
                        {
                            "index": 0,
                            "finish_reason": "stop",
                            "message": {"role": "assistant", "content": f"a robot arm, {len(images)} frames"},
                        }
                    ],
                    "usage": {"prompt_tokens": 1, "completion_tokens": 1, "total_tokens": 2},
                }
                data = json.dumps(answer).encode()
                self.send_response(200)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/v1"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()


@pytest.fixture
def vlm():
    m = MockVLM()
    yield m
    m.server.shutdown()


@pytest.fixture(scope="module")
def ingested(tmp_path_factory):
    root = tmp_path_factory.mktemp("caption")
    traj, _ = base_parts()
    for name in ("a", "b", "c"):
        write_episode(root / "src", name, traj.time_slice(0, 30), seed=1)
    write_episode(root / "src", "d", traj.time_slice(0, 30), seed=2, source="droid")
    run = root / "run"
    run_ingest(str(root / "src"), "npz", str(run), workers=1, shard_size=1, progress=False)
    return run


def test_frame_rates_follow_the_paper():
    cfg = CaptionConfig(base_url="http://x", model="m")
    assert len(frame_indices(81, 15.0, "rh20t_cfg5", cfg)) == 81  # 15 fps: every frame of a 15 fps episode
    np.testing.assert_array_equal(frame_indices(81, 30.0, "egodex", cfg), np.arange(0, 81, 2))
    assert len(frame_indices(900, 15.0, "droid", cfg)) == 120  # 2 fps for DROID: 60 s -> 120 frames
    assert len(frame_indices(15 * 90, 15.0, "egodex", cfg)) == 180  # long episode (90 s > 60 s): 2 fps
    assert len(frame_indices(15 * 50, 15.0, "egodex", cfg)) == 256  # thinned to max_frames


def test_caption_retries_caches_and_keeps_to_its_budget(tmp_path, ingested, vlm):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(ingested, run)
    cfg = CaptionConfig(base_url=vlm.url, model="qwen3-vl", budget=2, max_retries=2)
    vlm.fail = 1  # the first request fails once; the SDK retries it
    first = run_caption(str(run), cfg, workers=1, shard_size=1, progress=False)
    assert len(vlm.requests) == 3 and len(first.incomplete) == 2  # two episodes deferred by the budget
    body = vlm.requests[-1]["body"]
    assert vlm.requests[-1]["path"] == "/v1/chat/completions" and body["model"] == "qwen3-vl"
    assert body["messages"][0] == {"role": "system", "content": SYSTEM_PROMPT}
    assert SYSTEM_PROMPT.startswith("You are a video captioning specialist") and "80-100 words" in SYSTEM_PROMPT
    with pytest.raises(StageIncomplete):
        read_stage(str(run / "caption"))
    second = run_caption(
        str(run), CaptionConfig(base_url=vlm.url, model="qwen3-vl"), workers=1, shard_size=1, progress=False
    )
    assert len(vlm.requests) == 5 and not second.incomplete  # only the two deferred ones were asked
    rows = {r["id"]: r for r in read_stage(str(run / "caption"))}
    assert rows["droid/d"]["caption"] == "a robot arm, 4 frames"  # 30 frames at 2 fps: 0, 7.5, 15, 22.5
    assert rows["src/a"]["caption"] == "a robot arm, 30 frames" and rows["src/a"]["caption_value"] == 30
    # the cache answers a fresh run of the stage without a single request
    shutil.rmtree(run / "caption" / "completions")
    run_caption(str(run), CaptionConfig(base_url=vlm.url, model="qwen3-vl"), workers=1, shard_size=1, progress=False)
    assert len(vlm.requests) == 5


def test_endpoint_failure_is_recorded_and_retried_next_run(tmp_path, ingested, vlm):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(ingested, run)
    vlm.always_fail = True
    res = run_caption(
        str(run), CaptionConfig(base_url=vlm.url, model="m", max_retries=1), workers=1, shard_size=4, progress=False
    )
    assert res.incomplete == ["part-000000"] and len(vlm.requests) == 8  # 4 episodes x (1 + 1 retry)
    rows = rows_from_parquet((run / "caption" / "shards" / "part-000000.parquet").read_bytes())
    assert {r["caption_status"] for r in rows} == {"failed"} and "500" in rows[0]["caption_reason"]
    vlm.always_fail = False
    assert not run_caption(
        str(run), CaptionConfig(base_url=vlm.url, model="m"), workers=1, shard_size=4, progress=False
    ).incomplete
