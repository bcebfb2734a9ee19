"""VLM judges against a loopback mock of an OpenAI-compatible server (127.0.0.1 only, no internet)."""

import argparse
import base64
import json
import re
import threading
import time
import warnings
from collections import Counter
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import cv2
import numpy as np
import pytest
from _paths import REPO

from oscar_core.metrics import (
    PAIRWISE_SYSTEM_PROMPT,
    SUCCESS_SYSTEM_PROMPT,
    JudgeClip,
    JudgePair,
    MalformedAnswer,
    MetricInputError,
    PairwiseJudge,
    SuccessJudge,
    add_eval_parser,
    fit_bradley_terry,
    pairs_by_session,
    parse_pairwise_answer,
    parse_success_answer,
    preferences_from_verdicts,
    sample_frame_indices,
    success_by_policy,
)
from oscar_core.metrics.judge import PAPER_SUCCESS_PROMPT
from oscar_core.metrics.policy import BradleyTerryWarning

MODEL = "mock-vlm-7b"
VALID = '{"binary": 1, "partial": 100, "reason": "The cup is in the bowl."}'


# --------------------------------------------------------------------------- #
# the mock server
# --------------------------------------------------------------------------- #
def _decode(url: str) -> np.ndarray:
    head, data = url.split(",", 1)
    assert head in ("data:image/jpeg;base64", "data:image/png;base64")
    img = cv2.imdecode(np.frombuffer(base64.b64decode(data), np.uint8), cv2.IMREAD_COLOR)
    assert img is not None
    return img[..., ::-1]


class MockVLM:
    """Behaviour chosen by a keyword in the instruction; counts every request; keeps the bodies."""

    def __init__(self):
        self.lock = threading.Lock()
        self.bodies, self.headers = [], []
        self.per_instruction = Counter()
        self.in_flight = self.max_in_flight = 0
        self.times = []

    @property
    def count(self):
        with self.lock:
            return len(self.bodies)

    def reply(self, body):
        user = body["messages"][-1]["content"]
        text = user[0]["text"]
        found = re.match(r"Instruction: (.*)", text) or re.search(r"\nTask: (.*)", text)
        instruction = found.group(1)
        with self.lock:
            self.per_instruction[instruction] += 1
            n = self.per_instruction[instruction]
        if body["messages"][0]["content"] == PAIRWISE_SYSTEM_PROMPT:
            return self.pairwise(instruction, user)
        if "valid" in instruction:
            return 200, VALID
        if "fenced" in instruction:
            return 200, '```json\n{"binary": 0, "partial": 40, "reason": "Grasped, not placed."}\n```'
        if "malformed" in instruction:
            return 200, "The robot clearly succeeded, I would say 1."
        if "flaky" in instruction:
            return (500, None) if n == 1 else (200, VALID)
        if "ratelimit" in instruction:
            return (429, None) if n == 1 else (200, VALID)
        if "waitlimit" in instruction:  # 429 with Retry-After: 1 the first time
            with self.lock:
                self.times.append(time.monotonic())
            return (4291, None) if n == 1 else (200, VALID)
        if "slow-once" in instruction:
            return ("sleep", None) if n == 1 else (200, VALID)
        if "slow-always" in instruction:
            return "sleep", None
        if "shape" in instruction:
            return "raw", json.dumps({"result": {"binary": 1}})
        if "badrequest" in instruction:
            return 400, None
        if "hold" in instruction:
            with self.lock:
                self.in_flight += 1
                self.max_in_flight = max(self.max_in_flight, self.in_flight)
            time.sleep(0.15)
            with self.lock:
                self.in_flight -= 1
            return 200, VALID
        raise AssertionError(f"unexpected instruction {instruction!r}")

    @staticmethod
    def pairwise(instruction, user):
        images = [p["image_url"]["url"] for p in user if p["type"] == "image_url"]
        labels = [p["text"] for p in user if p["type"] == "text"]
        if any("left" in t for t in labels):  # side by side: A is the left half of every image
            img = _decode(images[0]).astype(float)
            w = (img.shape[1] - 8) // 2
            a, b = img[:, :w].mean(), img[:, -w:].mean()
        else:
            n_a = int(re.search(r"Attempt A, (\d+) frames", labels[1]).group(1))
            a, b = _decode(images[0]).mean(), _decode(images[n_a]).mean()
        darker = "prefer darker" in instruction
        if abs(a - b) < 1:
            winner = "tie"
        else:
            winner = "A" if (a > b) != darker else "B"
        return 200, json.dumps({"winner": winner, "reason": f"brightness {a:.0f} vs {b:.0f}"})


@pytest.fixture
def server():
    mock = MockVLM()

    class Handler(BaseHTTPRequestHandler):
        def do_POST(self):
            body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
            with mock.lock:
                mock.bodies.append(body)
                mock.headers.append({k.lower(): v for k, v in self.headers.items()})
            assert self.path == "/v1/chat/completions"
            code, content = mock.reply(body)
            if code == "sleep":
                time.sleep(2.0)  # past the client's timeout (_judge: 1 s, wide enough for a loaded machine)
                code, content = 200, VALID
            retry_after = "0"
            if code == 4291:
                code, retry_after = 429, "1"
            if code == "raw":
                payload = content.encode()
                code = 200
            elif code == 200:
                payload = json.dumps(
                    {
                        "id": "x",
                        "object": "chat.completion",
                        "model": body["model"],
                        "choices": [
                            {"index": 0, "finish_reason": "stop", "message": {"role": "assistant", "content": content}}
                        ],
                        "usage": {"prompt_tokens": 1000, "completion_tokens": 20, "total_tokens": 1020},
                    }
                ).encode()
            else:  # like some servers, echo the key in the error (the client must mask it)
                auth = self.headers.get("Authorization")
                payload = json.dumps({"error": {"message": f"mock {code}, key {auth}"}}).encode()
            try:
                self.send_response(code)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(payload)))
                if code == 429:
                    self.send_header("Retry-After", retry_after)
                self.end_headers()
                self.wfile.write(payload)
            except OSError:
                pass  # the client gave up (timeout)

        def log_message(self, *args):
            pass

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    httpd.daemon_threads = True
    httpd.handle_error = lambda *a: None
    thread = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    mock.url = f"http://127.0.0.1:{httpd.server_address[1]}/v1"
    yield mock
    httpd.shutdown()
    httpd.server_close()


@pytest.fixture(autouse=True)
def _no_env(monkeypatch):
    for var in ("OSCAR_JUDGE_BASE_URL", "OSCAR_JUDGE_MODEL", "OSCAR_JUDGE_API_KEY"):
        monkeypatch.delenv(var, raising=False)


def _video(seed, frames=40, size=(24, 32), value=None):
    if value is not None:
        return np.full((frames, *size, 3), value, dtype=np.uint8)
    return np.random.default_rng(seed).integers(0, 256, (frames, *size, 3), dtype=np.uint8)


def _judge(server, tmp_path, **kw):
    opts = dict(
        base_url=server.url,
        model=MODEL,
        timeout=1.0,
        max_attempts=3,
        backoff=0.01,
        concurrency=4,
        cache_dir=tmp_path / "cache",
    )
    opts.update(kw)
    return SuccessJudge(**opts)


# --------------------------------------------------------------------------- #
# strict parsing
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize(
    "text, expected",
    [
        (VALID, {"binary": 1, "partial": 100, "reason": "The cup is in the bowl."}),
        ('  {"partial": 0, "reason": "nothing", "binary": 0}\n', {"binary": 0, "partial": 0, "reason": "nothing"}),
        (
            '```json\n{"binary": 0, "partial": 55, "reason": "half"}\n```',
            {"binary": 0, "partial": 55, "reason": "half"},
        ),
        ('```\n{"binary": 1, "partial": 90, "reason": "ok"}\n```', {"binary": 1, "partial": 90, "reason": "ok"}),
    ],
)
def test_parse_success_answer_accepts_exact_objects(text, expected):
    assert parse_success_answer(text) == expected


@pytest.mark.parametrize(
    "text, message",
    [
        ("", "empty"),
        ("Success!", "one JSON object"),
        ('Here it is: {"binary": 1, "partial": 100, "reason": "x"}', "one JSON object"),
        ('{"binary": 1, "partial": 100, "reason": "x"} Hope that helps.', "not one valid JSON object"),
        ('```json\n{"binary": 1, "partial": 100, "reason": "x"}\n``` extra', "one JSON object"),
        ('[{"binary": 1, "partial": 100, "reason": "x"}]', "one JSON object"),
        ('{"binary": 1, "partial": 100}', "missing ['reason']"),
        ('{"binary": 1, "partial": 100, "reason": "x", "confidence": 0.9}', "extra ['confidence']"),
        ('{"binary": true, "partial": 100, "reason": "x"}', "'binary'"),
        ('{"binary": "1", "partial": 100, "reason": "x"}', "'binary'"),
        ('{"binary": 2, "partial": 100, "reason": "x"}', "'binary'"),
        ('{"binary": 1, "partial": 100.0, "reason": "x"}', "'partial'"),
        ('{"binary": 1, "partial": 101, "reason": "x"}', "'partial'"),
        ('{"binary": 1, "partial": -1, "reason": "x"}', "'partial'"),
        ('{"binary": 1, "partial": "80", "reason": "x"}', "'partial'"),
        ('{"binary": 1, "partial": NaN, "reason": "x"}', "NaN"),
        ('{"binary": 1, "partial": 100, "reason": "  "}', "'reason'"),
        ('{"binary": 1, "partial": 100, "reason": null}', "'reason'"),
        ('{"binary": 1, "binary": 0, "partial": 100, "reason": "x"}', "duplicate"),
    ],
)
def test_parse_success_answer_rejects_everything_else(text, message):
    with pytest.raises(MalformedAnswer, match=re.escape(message)):
        parse_success_answer(text)


def test_parse_pairwise_answer():
    assert parse_pairwise_answer('{"winner": "A", "reason": "r"}') == {"winner": "A", "reason": "r"}
    assert parse_pairwise_answer('```json\n{"reason": "r", "winner": "tie"}\n```')["winner"] == "tie"
    for bad in (
        '{"winner": "a", "reason": "r"}',
        '{"winner": "Tie", "reason": "r"}',
        '{"winner": "A"}',
        '{"winner": 1, "reason": "r"}',
        '{"winner": "A", "reason": "r", "score": 3}',
        "A",
    ):
        with pytest.raises(MalformedAnswer):
            parse_pairwise_answer(bad)


def test_sample_frame_indices():
    idx = sample_frame_indices(121, 32)
    assert len(idx) == 32 and idx[0] == 0 and idx[-1] == 120 and np.all(np.diff(idx) > 0)
    assert np.array_equal(idx, np.rint(np.linspace(0, 120, 32)).astype(int))
    assert np.array_equal(sample_frame_indices(5, 32), np.arange(5))  # fewer frames: all of them
    assert np.array_equal(sample_frame_indices(33, 32), np.rint(np.linspace(0, 32, 32)).astype(int))
    assert sample_frame_indices(9, 1).tolist() == [8]  # one frame: the end state
    for total in range(2, 60):
        for n in range(2, total + 1):
            assert len(set(sample_frame_indices(total, n).tolist())) == n


# --------------------------------------------------------------------------- #
# success judge against the mock server
# --------------------------------------------------------------------------- #
def test_success_judge_statuses_retries_request_body_and_cache(server, tmp_path):
    kinds = ["valid", "fenced", "malformed", "flaky", "ratelimit", "slow-once", "slow-always", "shape", "badrequest"]
    clips = [
        JudgeClip(
            f"s{k}/{kind}",
            _video(k, size=(90, 160)),
            f"{kind}: put the cup in the bowl",
            policy=f"p{k % 3}",
            session=f"s{k}",
        )
        for k, kind in enumerate(kinds)
    ]
    clips.append(JudgeClip("short", _video(99, frames=5), "valid but short clip", policy="p0"))
    judge = _judge(server, tmp_path, max_side=64, api_key="sk-secret-123")
    t0 = time.monotonic()
    verdicts = judge.judge_many(clips)
    assert time.monotonic() - t0 < 8
    assert [v.clip for v in verdicts] == [c.name for c in clips]  # nothing lost, input order
    by = {v.clip.split("/")[-1]: v for v in verdicts}

    ok = by["valid"]
    assert (ok.status, ok.binary, ok.partial, ok.reason, ok.attempts, ok.cached) == (
        "ok",
        1,
        100,
        "The cup is in the bowl.",
        1,
        False,
    )
    assert (ok.frames_total, ok.frames_sent, ok.model) == (40, 32, MODEL)
    assert (by["fenced"].status, by["fenced"].binary, by["fenced"].partial) == ("ok", 0, 40)
    mal = by["malformed"]
    assert mal.status == "malformed" and mal.binary is None and mal.partial is None
    assert mal.raw == "The robot clearly succeeded, I would say 1." and "JSON object" in mal.error
    for kind in ("flaky", "ratelimit", "slow-once"):  # one failed attempt, then success
        v = by[kind]
        assert (v.status, v.attempts, len(v.attempt_errors)) == ("ok", 2, 1), v
    assert by["flaky"].attempt_errors[0].startswith("HTTP 500")
    assert by["ratelimit"].attempt_errors[0].startswith("HTTP 429")
    assert by["slow-once"].attempt_errors[0].startswith("timeout")
    slow = by["slow-always"]
    # a timed-out request is retried once at most (max_timeout_retries=1), although max_attempts is 3
    assert (slow.status, slow.attempts, slow.binary) == ("error", 2, None)
    assert all(e.startswith("timeout") for e in slow.attempt_errors)
    assert "timed out 2 time(s); not retried beyond max_timeout_retries=1" in slow.error
    shape = by["shape"]  # a 200 that is not a chat completion: an error, not retried, body kept
    assert (shape.status, shape.attempts) == ("error", 1) and "not an OpenAI chat completion" in shape.error
    assert json.loads(shape.raw) == {"result": {"binary": 1}}
    bad = by["badrequest"]
    assert (bad.status, bad.attempts) == ("error", 1) and "HTTP 400" in bad.error
    assert "key Bearer ***" in bad.raw and "key Bearer ***" in bad.error  # the echoed key is masked
    short = by["short"]
    assert (short.status, short.frames_total, short.frames_sent) == ("ok", 5, 5)

    # request bodies: model, the paper's prompt word for word (one user message, no system message), the
    # instruction, one image per sampled frame, resized
    for body, headers in zip(server.bodies, server.headers):
        assert body["model"] == MODEL and set(body) == {"model", "messages"}
        assert headers["authorization"] == "Bearer sk-secret-123"
        (user,) = body["messages"]
        assert user["role"] == "user" and user["content"][0]["type"] == "text"
        instruction = re.search(r"\nTask: (.*)\n", user["content"][0]["text"]).group(1)
        assert user["content"][0]["text"] == PAPER_SUCCESS_PROMPT.replace("{instruction}", instruction)
        images = [p["image_url"]["url"] for p in user["content"][1:]]
        assert all(p["type"] == "image_url" for p in user["content"][1:])
        n = 5 if "short" in instruction else 32
        assert len(images) == n
        assert "put the cup in the bowl" in user["content"][0]["text"] or "short" in instruction
        shape_hw = _decode(images[0]).shape
        assert shape_hw == ((36, 64, 3) if "short" not in instruction else (24, 32, 3))
    assert server.count == 1 + 1 + 1 + 2 + 2 + 2 + 2 + 1 + 1 + 1
    assert sum(v.attempts for v in verdicts) == server.count
    assert "sk-secret" not in json.dumps([v.to_dict() for v in verdicts]) + repr(judge.client)
    assert "sk-secret" not in "".join(p.read_text() for p in (tmp_path / "cache").glob("*.json"))

    # rerun: ok and malformed come from the cache (no request); failures are asked again
    before = server.count
    again = _judge(server, tmp_path, max_side=64, max_attempts=1).judge_many(clips)
    assert [(v.status, v.binary, v.partial) for v in again if v.status != "error"] == [
        (v.status, v.binary, v.partial) for v in verdicts if v.status != "error"
    ]
    cached = [v for v in again if v.cached]
    assert {v.clip.split("/")[-1] for v in cached} == {
        "valid",
        "fenced",
        "malformed",
        "flaky",
        "ratelimit",
        "slow-once",
        "short",
    }
    assert all(v.attempts == 0 and v.frames_sent == w.frames_sent for v, w in zip(again, verdicts) if v.cached)
    assert server.count - before == 3  # slow-always, shape, badrequest: one attempt each
    files = sorted((tmp_path / "cache").glob("*.json"))
    assert len(files) == 7 and {json.loads(f.read_text())["key"] for f in files} == {v.cache_key for v in cached}
    assert not [p for p in (tmp_path / "cache").iterdir() if p.suffix != ".json"]  # no temporaries left

    # the key covers model, prompt settings and content: any change misses the cache
    valid = [clips[0]]
    for kw, clip in (
        ({"n_frames": 16}, valid[0]),
        ({"model": "other-model"}, valid[0]),
        ({"max_side": 48}, valid[0]),
        ({}, JudgeClip(valid[0].name, valid[0].video, valid[0].instruction + " now", "p0")),
        ({}, JudgeClip(valid[0].name, _video(123, size=(90, 160)), valid[0].instruction, "p0")),
    ):
        opts = {"max_side": 64, **kw}
        v = _judge(server, tmp_path, **opts).judge(clip)
        assert not v.cached and v.attempts == 1, kw
    v = _judge(server, tmp_path, max_side=64).judge(clips[0])
    assert v.cached and v.attempts == 0

    summary = success_by_policy(verdicts)
    assert summary["p0"]["episodes"] == [1, 1, 1] and summary["p0"]["not_judged"] == 1  # short: ok
    assert summary["p1"] == {
        "success_rate": 0.5,
        "episodes": [0, 1],
        "mean_partial": 70.0,
        "judged": 2,
        "not_judged": 1,
    }  # fenced (0, 40), ratelimit (1, 100), shape (error: left out)
    assert summary["p2"]["episodes"] == [1] and summary["p2"]["not_judged"] == 2


def test_success_judge_video_files_frame_folders_and_unreadable(server, tmp_path):
    from oscar_core.media.video import write_video

    frames = _video(1, frames=12, size=(32, 48))
    write_video(tmp_path / "a.mkv", frames, fps=10)
    write_video(tmp_path / "b", frames[:3], fps=10, format="png")
    (tmp_path / "broken.mp4").write_bytes(b"this is not a video")
    np.save(tmp_path / "c.npy", frames.astype(np.float32) / 255.0)
    clips = [
        JudgeClip("a", tmp_path / "a.mkv", "valid a"),
        JudgeClip("b", tmp_path / "b", "valid b"),
        JudgeClip("broken", str(tmp_path / "broken.mp4"), "valid broken"),
        JudgeClip("c", tmp_path / "c.npy", "valid c"),
    ]
    # no request here is meant to time out: a loaded machine must not turn a slow answer into an error
    verdicts = _judge(server, tmp_path, image_format="png", n_frames=8, timeout=10).judge_many(clips)
    assert [v.status for v in verdicts] == ["ok", "ok", "error", "ok"]
    assert [(v.frames_total, v.frames_sent) for v in verdicts if v.ok] == [(12, 8), (3, 3), (12, 8)]
    assert "broken.mp4" in verdicts[2].error and verdicts[2].attempts == 0
    first = next(b for b in server.bodies if "valid a" in b["messages"][-1]["content"][0]["text"])
    urls = [p["image_url"]["url"] for p in first["messages"][-1]["content"][1:]]
    # PNG is lossless: the sent frames are exactly the sampled ones
    for url, i in zip(urls, sample_frame_indices(12, 8)):
        assert url.startswith("data:image/png;base64,") and np.array_equal(_decode(url), frames[i])
    assert server.count == 3


@pytest.mark.parametrize("concurrency", [1, 3])
def test_concurrency_is_bounded(server, tmp_path, concurrency):
    clips = [JudgeClip(f"c{k}", _video(k, frames=3), f"hold {k}") for k in range(7)]
    verdicts = _judge(server, tmp_path, concurrency=concurrency, cache_dir=None, timeout=2).judge_many(clips)
    assert all(v.ok for v in verdicts) and [v.clip for v in verdicts] == [c.name for c in clips]
    assert server.max_in_flight == concurrency


def test_bad_input_is_reported_before_any_request(server, tmp_path, monkeypatch):
    judge = _judge(server, tmp_path)
    good = JudgeClip("good", _video(0), "valid task")
    with pytest.raises(MetricInputError, match="no such file"):
        judge.judge_many([good, JudgeClip("gone", tmp_path / "missing.mp4", "valid task")])
    with pytest.raises(MetricInputError, match="instruction"):
        judge.judge_many([good, JudgeClip("empty", _video(1), "   ")])
    with pytest.raises(MetricInputError, match="duplicates"):
        judge.judge_many([good, good])
    with pytest.raises(MetricInputError, match="shape"):
        judge.judge_many([JudgeClip("flat", np.zeros((4, 8, 8)), "valid task")])
    assert server.count == 0
    with pytest.raises(MetricInputError, match="OSCAR_JUDGE_BASE_URL"):
        SuccessJudge(model=MODEL)
    with pytest.raises(MetricInputError, match="OSCAR_JUDGE_MODEL"):
        SuccessJudge(base_url=server.url)
    with pytest.raises(MetricInputError, match="http"):
        SuccessJudge(base_url="127.0.0.1:8000", model=MODEL)
    for kw in (
        {"n_frames": 0},
        {"concurrency": 0},
        {"image_format": "gif"},
        {"max_attempts": 0},
        {"timeout": 0},
        {"max_side": 4},
    ):
        with pytest.raises(MetricInputError):
            _judge(server, tmp_path, **kw)
    # endpoint from the environment (and the base URL may already end in /chat/completions)
    monkeypatch.setenv("OSCAR_JUDGE_BASE_URL", server.url + "/chat/completions")
    monkeypatch.setenv("OSCAR_JUDGE_MODEL", "env-model")
    v = SuccessJudge(timeout=2).judge(good)
    assert v.ok and server.bodies[-1]["model"] == "env-model" and "authorization" not in server.headers[-1]


def test_sampling_fields_and_unreachable_server(server, tmp_path, refused_port):
    judge = _judge(server, tmp_path, temperature=0.0, max_tokens=64, extra_body={"reasoning_effort": "high"})
    assert judge.judge(JudgeClip("x", _video(0), "valid x")).ok
    body = server.bodies[-1]
    assert (body["temperature"], body["max_completion_tokens"], body["reasoning_effort"]) == (0.0, 64, "high")
    assert "max_tokens" not in body  # OpenAI's newer models reject max_tokens; older servers: token_field
    assert (
        _judge(server, tmp_path, max_tokens=64, token_field="max_tokens").judge(JudgeClip("y", _video(1), "valid y")).ok
    )
    assert server.bodies[-1]["max_tokens"] == 64 and "max_completion_tokens" not in server.bodies[-1]
    # nothing listens on this port: connection errors are retried, then the whole run stops (it never answered;
    # test_an_endpoint_that_refuses_every_connection_stops_the_run); after answers they stay per-clip errors
    # (test_refused_connections_after_answers_stay_per_clip_errors)
    from oscar_core.metrics import JudgeEndpointUnreachable

    dead = SuccessJudge(base_url=_refusing_url(refused_port), model=MODEL, timeout=1, max_attempts=2, backoff=0.01)
    with pytest.raises(JudgeEndpointUnreachable):
        dead.judge(JudgeClip("x", _video(0), "valid x"))
    assert dead.client.requests_sent == 2


# --------------------------------------------------------------------------- #
# pairwise judge
# --------------------------------------------------------------------------- #
BRIGHTNESS = {"best": 220, "good": 160, "fair": 100, "poor": 40}


def _session_clips(session, instruction, size=(24, 32)):
    return [
        JudgeClip(f"{session}/{p}", _video(0, frames=20, size=size, value=v), instruction, policy=p, session=session)
        for p, v in BRIGHTNESS.items()
    ]


def test_pairwise_randomised_order_maps_back_and_feeds_bradley_terry(server, tmp_path):
    clips = (
        _session_clips("s1", "stack the blocks")
        + _session_clips("s2", "open the drawer")
        + _session_clips("s3", "stack the blocks, prefer darker")
    )
    pairs = pairs_by_session(clips)
    assert len(pairs) == 3 * 6 and all(p.a.session == p.b.session for p in pairs)
    judge = PairwiseJudge(
        base_url=server.url, model=MODEL, seed=7, n_frames=4, timeout=2, backoff=0.01, cache_dir=tmp_path / "cache"
    )
    verdicts = judge.compare_many(pairs)
    assert all(v.ok for v in verdicts)
    swapped = [v.swapped for v in verdicts]
    assert any(swapped) and not all(swapped)  # both orders are used
    for v in verdicts:
        shown_first = v.b if v.swapped else v.a
        assert v.shown_first == shown_first
        expected = min if "darker" in v.instruction else max
        assert v.winner_policy == expected((v.a, v.b), key=BRIGHTNESS.get), v
        assert v.model_winner == ("A" if v.winner_policy == shown_first else "B")
    # (the server picks by the brightness of what it was shown as A and B, so a wrong mapping fails above)
    assert server.count == len(pairs)
    for body in server.bodies:
        assert body["model"] == MODEL and body["messages"][0]["content"] == PAIRWISE_SYSTEM_PROMPT
        images = [p for p in body["messages"][1]["content"] if p["type"] == "image_url"]
        assert len(images) == 8
    # the order depends on the seed and the pair id only, not on the list order
    rev = PairwiseJudge(base_url=server.url, model=MODEL, seed=7, n_frames=4, cache_dir=tmp_path / "cache")
    assert [rev.swapped(p) for p in pairs[::-1]] == swapped[::-1]
    again = rev.compare_many(pairs[::-1])
    assert all(v.cached for v in again) and server.count == len(pairs)
    assert [(v.pair, v.winner) for v in again[::-1]] == [(v.pair, v.winner) for v in verdicts]
    other_seed = PairwiseJudge(base_url=server.url, model=MODEL, seed=8, n_frames=4)
    assert [other_seed.swapped(p) for p in pairs] != swapped

    prefs = preferences_from_verdicts(verdicts)
    assert len(prefs) == len(pairs)
    for p, v in zip(prefs, verdicts):
        assert (p.a, p.b) == (v.a, v.b) and p.outcome == {"a": 2, "b": 0, "tie": 1}[v.winner]
    with warnings.catch_warnings():
        warnings.simplefilter("error", BradleyTerryWarning)  # the upset session makes every score finite
        bt = fit_bradley_terry(prefs)
    assert bt.ranking() == ["best", "good", "fair", "poor"]


def test_pairwise_side_by_side_ties_and_malformed(server, tmp_path):
    a = JudgeClip("s/a", _video(0, frames=10, size=(30, 40), value=120), "compare", policy="a", session="s")
    b = JudgeClip("s/b", _video(0, frames=6, size=(60, 80), value=120), "compare", policy="b", session="s")
    c = JudgeClip("s/c", _video(0, frames=6, size=(30, 40), value=250), "compare", policy="c", session="s")
    judge = PairwiseJudge(base_url=server.url, model=MODEL, layout="side_by_side", n_frames=8, timeout=2, concurrency=1)
    verdicts = judge.compare_many(pairs_by_session([a, b, c]))
    assert [v.pair for v in verdicts] == ["s/a vs s/b", "s/a vs s/c", "s/b vs s/c"]
    assert verdicts[0].winner == "tie" and verdicts[0].winner_policy is None
    assert verdicts[0].preference().outcome == 1
    assert verdicts[1].winner_policy == "c" and verdicts[2].winner_policy == "c"
    for body, v in zip(server.bodies, verdicts):
        images = [p["image_url"]["url"] for p in body["messages"][1]["content"] if p["type"] == "image_url"]
        assert len(images) == 6 and v.frames_sent == (6, 6)  # cut to the shorter clip
        h = {"a": 30, "b": 60, "c": 30}[v.shown_first]  # the right half is scaled to the left half's height
        assert _decode(images[0]).shape == (h, 2 * (h * 4 // 3) + 8, 3)
    # a malformed pairwise answer is kept per pair and never becomes a preference
    mal = judge._from_answer(JudgePair(a, c), False, "A is better", {}, attempts=1, cached=False, errors=())
    assert mal.status == "malformed" and mal.raw == "A is better" and mal.preference() is None
    assert preferences_from_verdicts([mal, *verdicts]) == [v.preference() for v in verdicts]


def test_pairs_by_session_rules():
    s1 = _session_clips("s1", "task one")
    assert len(pairs_by_session(s1[:3])) == 3
    loose = [
        JudgeClip("x", _video(0), "same task", policy="p"),
        JudgeClip("y", _video(0), "same task", policy="q"),
        JudgeClip("z", _video(0), "other task", policy="r"),
    ]
    assert [(p.a.name, p.b.name) for p in pairs_by_session(loose)] == [("x", "y")]  # grouped by instruction
    same_policy = [
        JudgeClip("e1", _video(0), "t", policy="p", session="s"),
        JudgeClip("e2", _video(0), "t", policy="p", session="s"),
    ]
    assert pairs_by_session(same_policy) == []
    with pytest.raises(MetricInputError, match="same instruction"):
        pairs_by_session(
            [
                JudgeClip("a", _video(0), "t1", policy="p", session="s"),
                JudgeClip("b", _video(0), "t2", policy="q", session="s"),
            ]
        )
    with pytest.raises(MetricInputError, match="a policy other than"):
        PairwiseJudge(base_url="http://127.0.0.1:9/v1", model=MODEL).compare_many([JudgePair(*same_policy)])


# --------------------------------------------------------------------------- #
# the CLI
# --------------------------------------------------------------------------- #
def run(capsys, *argv):
    parser = argparse.ArgumentParser(prog="oscar")
    add_eval_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["eval", *map(str, argv)])
    code = args.func(args)
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_judge_and_pairwise_feed_eval_policies(server, tmp_path, capsys):
    root = tmp_path / "rollouts"
    for session in ("s1", "s2"):
        (root / session).mkdir(parents=True)
        for p, v in BRIGHTNESS.items():
            np.save(root / session / f"{p}.npy", _video(0, frames=12, value=v))
    (root / "s2" / "poor.npy").unlink()
    np.save(root / "s2" / "oddball.npy", _video(0, frames=12, value=40))
    tasks = {
        "s1": "valid: stack the blocks",
        "s2": {"instruction": "valid: open the drawer"},
        "s2/oddball": {"policy": "poor"},
        "unused/folder": "ignored",
    }
    (tmp_path / "tasks.json").write_text(json.dumps(tasks))
    common = [
        "--tasks",
        tmp_path / "tasks.json",
        "--base-url",
        server.url,
        "--model",
        MODEL,
        "--timeout",
        2,
        "--cache",
        tmp_path / "cache",
    ]
    code, out, err = run(
        capsys,
        "judge",
        "--videos",
        root,
        *common,
        "--frames",
        6,
        "--out",
        tmp_path / "j.json",
        "--wm-out",
        tmp_path / "wm.json",
    )
    assert code == 0, out + err
    data = json.loads((tmp_path / "j.json").read_text())
    assert data["summary"] == {
        "total": 8,
        "ok": 8,
        "malformed": 0,
        "error": 0,
        "cached": 0,
        "requests": 8,
        "retries": 0,
        "usage": {"prompt_tokens": 8000, "completion_tokens": 160, "total_tokens": 8160},
    }  # summed from the responses
    assert data["clips"][0]["usage"] == {"prompt_tokens": 1000, "completion_tokens": 20, "total_tokens": 1020}
    rows = {c["clip"]: c for c in data["clips"]}
    assert rows["s2/oddball"]["policy"] == "poor" and rows["s2/oddball"]["session"] == "s2"
    assert rows["s1/good"]["instruction"] == "valid: stack the blocks" and rows["s1/good"]["frames_sent"] == 6
    assert data["judge"]["model"] == MODEL and data["judge"]["n_frames"] == 6
    wm = json.loads((tmp_path / "wm.json").read_text())
    assert wm["best"] == {"success_rate": 1.0, "episodes": [1, 1], "mean_partial": 100.0}
    assert "8 clips: 8 ok" in out
    # the same through a glob; everything now comes from the cache
    code, out, _ = run(capsys, "judge", "--videos", f"{root}/*/*.npy", *common, "--frames", 6, "--json")
    assert code == 0 and json.loads(out)["summary"]["cached"] == 8 and server.count == 8

    code, out, err = run(
        capsys,
        "pairwise",
        "--videos",
        root,
        *common,
        "--frames",
        3,
        "--seed",
        1,
        "--out",
        tmp_path / "pw.json",
        "--preferences-out",
        tmp_path / "prefs.jsonl",
    )
    pw = json.loads((tmp_path / "pw.json").read_text())
    assert len(pw["pairs"]) == 12 and pw["summary"]["ok"] == 12
    assert code == 0 and "best" in out
    assert [b["policy"] for b in pw["bradley_terry"]["board"]] == ["best", "good", "fair", "poor"]
    assert pw["bradley_terry"]["warnings"]  # a strict order: infinite MLE, reported
    lines = [json.loads(line) for line in (tmp_path / "prefs.jsonl").read_text().splitlines()]
    assert len(lines) == 12 and set(lines[0]) == {"a", "b", "winner", "pair"}

    real = {"best": 0.9, "good": 0.6, "fair": 0.3, "poor": 0.1}
    (tmp_path / "real.json").write_text(json.dumps(real))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BradleyTerryWarning)
        code, out, _ = run(
            capsys,
            "policies",
            "--real",
            tmp_path / "real.json",
            "--wm",
            tmp_path / "wm.json",
            "--preferences",
            tmp_path / "prefs.jsonl",
            "--json",
        )
    result = json.loads(out)
    assert code == 0 and result["metrics"]["spearman_rho"] == pytest.approx(1.0)
    assert result["ranked_by"]["wm"] == "bradley_terry_elo"


def test_cli_judge_reports_problems_and_bad_tasks(server, tmp_path, capsys):
    root = tmp_path / "r"
    root.mkdir()
    for name in ("a", "b", "c"):
        np.save(root / f"{name}.npy", _video(1, frames=4))
    tasks = tmp_path / "tasks.json"
    tasks.write_text(json.dumps({"a": "valid a", "b": "malformed b", "c": "shape c"}))
    code, out, _ = run(
        capsys,
        "judge",
        "--videos",
        root,
        "--tasks",
        tasks,
        "--base-url",
        server.url,
        "--model",
        MODEL,
        "--no-cache",
        "--max-attempts",
        1,
        "--out",
        tmp_path / "o.json",
    )
    assert code == 1
    assert re.search(r"malformed +b: malformed answer", out) and "[raw: The robot clearly" in out
    assert re.search(r"error +c: .*not an OpenAI chat completion", out)
    assert "3 clips: 1 ok, 1 malformed, 1 failed" in out
    assert len(json.loads((tmp_path / "o.json").read_text())["clips"]) == 3
    assert not (tmp_path / "cache").exists()

    for bad, match in (
        ({"a": "valid", "b": "valid"}, r"none for \['c'\]"),
        ({"a": "", "b": "x", "c": "x"}, "field 'a': expected a non-empty task instruction"),
        ({"a": {"instruction": "x", "polcy": "p"}, "b": "x", "c": "x"}, r"extra keys \['polcy'\]"),
        ([1, 2], "top level"),
    ):
        tasks.write_text(json.dumps(bad))
        with pytest.raises(MetricInputError, match=match):
            run(capsys, "judge", "--videos", root, "--tasks", tasks, "--base-url", server.url, "--model", MODEL)
    with pytest.raises(MetricInputError, match="no such file"):
        run(capsys, "judge", "--videos", tmp_path / "nope", "--tasks", tasks, "--base-url", server.url)
    with pytest.raises(MetricInputError, match="none"):
        run(capsys, "judge", "--videos", f"{tmp_path}/*.mkv", "--tasks", tasks, "--base-url", server.url)
    with pytest.raises(MetricInputError, match="a .json file"):
        run(capsys, "judge", "--videos", tasks, "--tasks", tasks, "--base-url", server.url)
    tasks.write_text(json.dumps({"a": "valid one video"}))
    code, out, _ = run(
        capsys,
        "judge",
        "--videos",
        root / "a.npy",
        "--tasks",
        tasks,
        "--base-url",
        server.url,
        "--model",
        MODEL,
        "--no-cache",
        "--json",
    )
    assert code == 0 and [c["clip"] for c in json.loads(out)["clips"]] == ["a"]
    with pytest.raises(MetricInputError, match="--extra-body"):
        tasks.write_text(json.dumps({"r": "valid"}))
        run(
            capsys,
            "judge",
            "--videos",
            root,
            "--tasks",
            tasks,
            "--base-url",
            server.url,
            "--model",
            MODEL,
            "--extra-body",
            "[1]",
        )
    assert server.count == 4


def test_docs_show_the_prompts_and_every_option():

    from oscar_core.metrics import judge as judge_module

    doc = (REPO / "docs" / "evaluation.md").read_text()
    for prompt in (PAPER_SUCCESS_PROMPT, SUCCESS_SYSTEM_PROMPT, PAIRWISE_SYSTEM_PROMPT):
        assert f"```text\n{prompt}\n```" in doc
    parser = argparse.ArgumentParser(prog="oscar")
    from oscar_core.evaluation.cli import add_run_parser

    ev = add_eval_parser(parser.add_subparsers(dest="command", required=True), extra_commands=(add_run_parser,))
    sub = next(a for a in ev._actions if isinstance(a, argparse._SubParsersAction))
    for name in ("judge", "pairwise", "policies", "run", "video", "weights"):
        parsers = [sub.choices[name]]
        if name == "weights":
            inner = next(a for a in parsers[0]._actions if isinstance(a, argparse._SubParsersAction))
            parsers = list(inner.choices.values())
        for action in [a for p in parsers for a in p._actions]:
            for opt in action.option_strings:
                if opt.startswith("--") and opt != "--help":
                    assert f"`{opt}" in doc or f"{opt} " in doc, f"{name} {opt} is not documented"
    user = judge_module.SUCCESS_USER_PROMPT.split("{instruction}")[0]
    assert user in doc


def test_retry_after_budget_and_dry_run(server, tmp_path, capsys):
    # Retry-After: 1 is honoured even though the backoff is 10 ms
    v = _judge(server, tmp_path, cache_dir=None, timeout=5).judge(JudgeClip("w", _video(0, frames=3), "waitlimit w"))
    assert (v.status, v.attempts) == ("ok", 2) and v.attempt_errors[0].startswith("HTTP 429")
    assert server.times and time.monotonic() - server.times[0] >= 0.95
    # a budget of 3 requests for 5 clips: 3 answered, 2 failed without a request, nothing cached for those
    clips = [JudgeClip(f"b{k}", _video(k, frames=3), f"valid {k}") for k in range(5)]
    before = server.count
    judge = _judge(server, tmp_path, max_requests=3, concurrency=1)
    verdicts = judge.judge_many(clips)
    assert server.count - before == 3 and judge.client.requests_sent == 3
    assert [v.status for v in verdicts] == ["ok", "ok", "ok", "error", "error"]
    assert "request budget of 3 requests spent" in verdicts[3].error and verdicts[3].attempts == 0
    assert judge.client.usage == {"prompt_tokens": 3000, "completion_tokens": 60, "total_tokens": 3060}
    again = _judge(server, tmp_path, max_requests=2).judge_many(clips)  # a re-run continues where it stopped
    assert [v.cached for v in again] == [True, True, True, False, False] and all(v.ok for v in again)
    # dry run: prints what would be sent, sends nothing
    root = tmp_path / "videos" / "s1"
    root.mkdir(parents=True)
    np.save(root / "pi0.npy", _video(1, frames=40, size=(288, 512)))
    np.save(root / "pg.npy", _video(2, frames=40, size=(288, 512)))
    (tmp_path / "tasks.json").write_text(json.dumps({"s1": "valid: put the cup in the bowl"}))
    before = server.count
    code, out, err = run(
        capsys,
        "judge",
        "--videos",
        tmp_path / "videos",
        "--tasks",
        tmp_path / "tasks.json",
        "--base-url",
        server.url,
        "--model",
        MODEL,
        "--cache",
        tmp_path / "c2",
        "--dry-run",
    )
    assert code == 0 and server.count == before, err
    assert "s1/pi0: 1 request to" in out and "32 images 512x288" in out and "nothing was sent" in out
    assert "| Task: valid: put the cup in the bowl" in out and "| Frames in temporal order:" in out
    code, out, _ = run(
        capsys,
        "judge",
        "--videos",
        tmp_path / "videos",
        "--tasks",
        tmp_path / "tasks.json",
        "--base-url",
        server.url,
        "--model",
        MODEL,
        "--cache",
        tmp_path / "c2",
        "--dry-run",
        "--json",
    )
    plan = json.loads(out)
    assert [r["images"] for r in plan["requests"]] == [32, 32] and server.count == before


def test_prompt_options(server, tmp_path):
    clip = JudgeClip("x", _video(0, frames=3), "valid x")
    assert _judge(server, tmp_path, prompt="oscar", cache_dir=None).judge(clip).ok
    system, user = server.bodies[-1]["messages"]
    assert system == {"role": "system", "content": SUCCESS_SYSTEM_PROMPT}
    assert (
        user["content"][0]["text"] == "Instruction: valid x\n\nThe 3 frames of the attempt follow, in temporal order."
    )
    assert (
        _judge(server, tmp_path, prompt="Rate this.\nTask: {instruction} ({n_frames} frames)\n", cache_dir=None)
        .judge(clip)
        .ok
    )
    (user,) = server.bodies[-1]["messages"]
    assert user["content"][0]["text"] == "Rate this.\nTask: valid x (3 frames)\n"
    with pytest.raises(MetricInputError, match="prompt"):
        _judge(server, tmp_path, prompt="no placeholder")


def test_pairwise_both_orders_reconciles_position_bias(server, tmp_path):
    clips = _session_clips("s1", "compare: put the cup in the bowl")[:2]  # best (bright) vs good (less bright)
    pair = pairs_by_session(clips)[0]
    v = PairwiseJudge(base_url=server.url, model=MODEL, cache_dir=None, both_orders=True, timeout=2).compare(pair)
    assert v.ok and v.orders_agree is True and v.winner == "a" and v.attempts == 2
    assert [o.swapped for o in v.orders] == [False, True] and [o.winner for o in v.orders] == ["a", "a"]
    assert v.usage == {"prompt_tokens": 2000, "completion_tokens": 40, "total_tokens": 2040}

    class Biased(PairwiseJudge):  # a judge that always answers "A": the orders disagree -> a tie
        def _compare_once(self, pair, swapped):
            from dataclasses import replace as _replace

            v = super()._compare_once(pair, swapped)
            shown = pair.b.policy_name if swapped else pair.a.policy_name
            return _replace(v, model_winner="A", winner="b" if swapped else "a", reason=f"{shown} first")

    v = Biased(base_url=server.url, model=MODEL, cache_dir=None, both_orders=True, timeout=2).compare(pair)
    assert v.ok and v.orders_agree is False and v.winner == "tie" and "disagree" in v.reason
    assert v.preference().outcome == 1  # a tie for Bradley-Terry


def test_retry_after_reads_seconds_and_http_dates():
    from oscar_core.metrics.judge_client import _retry_after

    now = 1_700_000_000.0  # 2023-11-14T22:13:20Z
    assert _retry_after({"Retry-After": "7"}, now) == 7.0
    assert _retry_after({"Retry-After": "-3"}, now) == 0.0
    assert _retry_after({"Retry-After": "Tue, 14 Nov 2023 22:13:50 GMT"}, now) == pytest.approx(30.0)
    assert _retry_after({"Retry-After": "Tuesday, 14-Nov-23 22:14:20 GMT"}, now) == pytest.approx(60.0)  # RFC 850
    assert _retry_after({"Retry-After": "Tue, 14 Nov 2023 22:00:00 GMT"}, now) == 0.0  # already past
    assert _retry_after({"Retry-After": "soon"}, now) is None
    assert _retry_after({"Retry-After": "inf"}, now) is None
    assert _retry_after({}, now) is None and _retry_after(None, now) is None


def _refusing_url(port: int) -> str:
    """The judge endpoint on ``port`` (the ``refused_port`` fixture: connections to it are refused)."""
    return f"http://127.0.0.1:{port}/v1"


def test_an_endpoint_that_refuses_every_connection_stops_the_run(tmp_path, refused_port):
    from oscar_core.metrics import JudgeEndpointUnreachable

    clips = [JudgeClip(f"s0/p{k}", _video(k, frames=4), "put the cup in the bowl") for k in range(6)]
    judge = SuccessJudge(
        base_url=_refusing_url(refused_port),
        model=MODEL,
        max_attempts=3,
        backoff=0.0,
        concurrency=2,
        cache_dir=tmp_path / "cache",
    )
    t0 = time.monotonic()
    with pytest.raises(
        JudgeEndpointUnreachable, match=r"refused all 3 connections and never answered.*--judge-base-url"
    ):
        judge.judge_many(clips)
    assert time.monotonic() - t0 < 10
    # it stops: no clip beyond the first few tried, and every later request fails at once without a connection
    assert judge.client.requests_sent <= 3 + 2 * 3
    sent = judge.client.requests_sent
    with pytest.raises(JudgeEndpointUnreachable):
        judge.judge_many(clips[:1])
    assert judge.client.requests_sent == sent and not list((tmp_path / "cache").glob("*.json"))


def test_refused_connections_after_answers_stay_per_clip_errors(server, tmp_path, refused_port):
    # the endpoint answered before: a later refusal is one clip's error, not the end of the run
    judge = SuccessJudge(base_url=server.url, model=MODEL, max_attempts=2, backoff=0.0)
    ok = judge.judge_many([JudgeClip("a", _video(1, frames=4), "valid a")])
    assert ok[0].status == "ok"
    judge.client._sdk = judge.client._sdk.with_options(base_url=_refusing_url(refused_port))
    (bad,) = judge.judge_many([JudgeClip("b", _video(2, frames=4), "valid b")])
    assert bad.status == "error" and "connection" in bad.error


def test_eval_judge_exits_non_zero_naming_the_unreachable_endpoint(tmp_path, capsys, refused_port):
    from oscar_core.cli import main

    root = tmp_path / "rollouts" / "s1"
    root.mkdir(parents=True)
    np.save(root / "p0.npy", _video(0, frames=4))
    (tmp_path / "tasks.json").write_text(json.dumps({"s1": "put the cup in the bowl"}))
    url = _refusing_url(refused_port)
    code = main(
        [
            "eval",
            "judge",
            "--videos",
            str(tmp_path / "rollouts"),
            "--tasks",
            str(tmp_path / "tasks.json"),
            "--base-url",
            url,
            "--model",
            MODEL,
            "--backoff",
            "0",
            "--no-cache",
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and f"the judge endpoint {url}/chat/completions refused all 5 connections" in err
