"""Rating backends behind one interface: a real local VLM path, a real HTTP endpoint, the prior, the cache."""
from __future__ import annotations

import base64
import io
import json
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np
import pytest
import torch
from PIL import Image

from sagp_batched.config import ConfigError, RatingConfig
from sagp_batched.rating import (
    CachedRater,
    OpenAIVLM,
    PriorRater,
    RatingError,
    VLMRater,
    VLMRequestError,
    get_rater,
)
from sagp_batched.semantics.zone_descriptions import describe_zones
from sagp_batched.rating.vlm import ModelAnswer
from sagp_batched.types import TASKS

STUDY_OBJECTS = (
    "025_mug", "019_pitcher_base", "005_tomato_soup_can", "035_power_drill", "037_scissors", "051_large_clamp",
    "011_banana", "040_large_marker", "003_cracker_box", "021_bleach_cleanser", "006_mustard_bottle",
    "002_master_chef_can", "007_tuna_fish_can", "010_potted_meat_can",
)
ZONES = {"top": "top: 30% of points", "middle": "middle: 40% of points", "bottom": "bottom: 25% of points",
         "protrusion": "protrusion: 5% of points"}
CROP = (np.random.default_rng(0).random((60, 80, 3)) * 255).astype(np.uint8)
GOOD_ANSWER = {
    "ratings": {"top": "dangerous", "middle": "acceptable", "bottom": "bad", "protrusion": "good"},
    "preferred": ["protrusion"], "avoid": ["top"], "approach": "side", "grasp_style": "hook", "max_tilt_deg": 15,
}


# --- transformers: a tiny randomly initialised Qwen2-VL saved to disk and loaded back like a real checkpoint.

@pytest.fixture(scope="module")
def tiny_qwen2_vl(tmp_path_factory):
    from transformers import AutoModelForImageTextToText, Qwen2Tokenizer, Qwen2VLConfig, Qwen2VLImageProcessorPil

    directory = tmp_path_factory.mktemp("tiny-qwen2-vl")
    vocab = {c: i for i, c in enumerate([chr(c) for c in range(33, 127)] + ["Ġ", "Ċ"])}
    tokenizer = Qwen2Tokenizer(vocab=vocab, merges=[], unk_token=None)
    specials = ["<|im_start|>", "<|im_end|>", "<|vision_start|>", "<|vision_end|>", "<|image_pad|>", "<|video_pad|>"]
    tokenizer.add_special_tokens({"additional_special_tokens": specials, "eos_token": "<|im_end|>", "pad_token": "<|endoftext|>"})
    ids = {s: tokenizer.convert_tokens_to_ids(s) for s in specials + ["<|endoftext|>"]}
    config = Qwen2VLConfig(
        text_config=dict(
            vocab_size=len(tokenizer), hidden_size=64, intermediate_size=128, num_hidden_layers=2, num_attention_heads=4,
            num_key_value_heads=2, rope_scaling={"type": "mrope", "mrope_section": [2, 3, 3]},
            eos_token_id=ids["<|im_end|>"], pad_token_id=ids["<|endoftext|>"], bos_token_id=ids["<|endoftext|>"],
        ),
        vision_config=dict(depth=2, embed_dim=32, hidden_size=64, num_heads=2, mlp_ratio=2, patch_size=14,
                           spatial_merge_size=2, temporal_patch_size=2),
        image_token_id=ids["<|image_pad|>"], video_token_id=ids["<|video_pad|>"],
        vision_start_token_id=ids["<|vision_start|>"], vision_end_token_id=ids["<|vision_end|>"],
    )
    torch.manual_seed(0)  # a fixed random model, so its (garbage) answer is the same every run
    AutoModelForImageTextToText.from_config(config).save_pretrained(directory)
    tokenizer.save_pretrained(directory)
    Qwen2VLImageProcessorPil(min_pixels=56 * 56, max_pixels=112 * 112).save_pretrained(directory)
    return directory


def test_local_vlm_runs_the_real_path_and_its_garbage_becomes_a_marked_neutral_rating(tiny_qwen2_vl, tmp_path):
    config = RatingConfig(backend="transformers", model=str(tiny_qwen2_vl), max_new_tokens=24, cache_dir=str(tmp_path))
    rater = get_rater(config)
    rating = rater.rate("025_mug", "mug", "t2", CROP, ZONES)
    assert rating.provenance.backend == "transformers" and rating.provenance.model == str(tiny_qwen2_vl)
    assert rating.provenance.latency_s > 0.0
    assert rating.raw_text, "the model generated and its tokens were decoded"
    # A random model's text is not a rating: it must be marked neutral, not turned into one.
    assert rating.is_neutral and rating.ratings == {}
    assert rater.queries == 1
    assert not list(tmp_path.glob("*.json")), "a neutral answer is not cached"


def test_local_vlm_stays_offline_for_an_unknown_model(tmp_path):
    config = RatingConfig(backend="transformers", model="no-such-org/no-such-vlm", cache_dir=str(tmp_path))
    rater = get_rater(config)  # nothing is loaded until a question needs the model
    with pytest.raises(RatingError, match="no-such-vlm"):
        rater.rate("025_mug", "mug", "t1", CROP, ZONES)


# --- openai: a real HTTP server on 127.0.0.1 that answers from a script.

class ScriptedEndpoint:
    """``script``: one (kind, value) a request, in order. ``refuses_schema``: a request carrying
    ``response_format`` is answered HTTP 400 (as by a server without structured output), using no script entry."""

    def __init__(self):
        self.script: list[tuple[str, object]] = []
        self.requests: list[dict] = []
        self.refuses_schema = False
        endpoint = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_POST(self):
                body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                endpoint.requests.append({"path": self.path, "body": body, "auth": self.headers.get("Authorization")})
                if endpoint.refuses_schema and "response_format" in body:
                    kind, value = "bad_request", None
                else:
                    kind, value = endpoint.script.pop(0)
                if kind == "sleep":
                    time.sleep(value)
                    kind, value = "answer", "late"
                if kind == "error":
                    status, text = 500, "overloaded"
                elif kind == "bad_request":
                    status, text = 400, json.dumps({"error": {"message": "Bad Request", "code": 400}})
                else:
                    status, text = 200, json.dumps({"choices": [{"message": {"role": "assistant", "content": value}}]})
                try:
                    self.send_response(status)
                    self.send_header("Content-Type", "application/json")
                    self.end_headers()
                    self.wfile.write(text.encode())
                except (BrokenPipeError, ConnectionResetError):
                    pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/v1"
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()


@pytest.fixture
def endpoint():
    server = ScriptedEndpoint()
    yield server
    server.server.shutdown()
    server.server.server_close()


def openai_rater(endpoint, tmp_path, **overrides):
    config = RatingConfig(backend="openai", model="served-vlm", endpoint=endpoint.url, cache_dir=str(tmp_path),
                          retry_backoff_s=0.01, timeout_s=2.0, api_key_env="SAGP_TEST_KEY", use_cache=False)
    for key, value in overrides.items():
        setattr(config, key, value)
    return get_rater(config)


def test_endpoint_good_answer_with_image_and_key(endpoint, tmp_path, monkeypatch):
    monkeypatch.setenv("SAGP_TEST_KEY", "secret-token")
    endpoint.script = [("answer", json.dumps(GOOD_ANSWER))]
    rating = openai_rater(endpoint, tmp_path).rate("025_mug", "mug", "t2", CROP, ZONES)
    assert rating.provenance.outcome == "ok" and rating.preferred == {"protrusion"}
    request = endpoint.requests[0]
    assert request["path"] == "/v1/chat/completions" and request["auth"] == "Bearer secret-token"
    body = request["body"]
    assert body["model"] == "served-vlm" and body["temperature"] == 0.0
    image_url = body["messages"][0]["content"][0]["image_url"]["url"]
    assert image_url.startswith("data:image/png;base64,")
    sent = np.asarray(Image.open(io.BytesIO(base64.b64decode(image_url.split(",", 1)[1]))))
    assert np.array_equal(sent, CROP)
    prompt = body["messages"][0]["content"][1]["text"]
    assert "protrusion: 5% of points" in prompt and "functional grasp" in prompt


def test_endpoint_is_asked_for_json_matching_the_answer_schema_and_the_rating_says_so(endpoint, tmp_path):
    from sagp_batched.rating.zone_rating import APPROACH_NAMES, GRASP_STYLES, RATING_LEVELS, ZoneRating

    endpoint.script = [("answer", json.dumps(GOOD_ANSWER))]
    rating = openai_rater(endpoint, tmp_path).rate("025_mug", "mug", "t2", CROP, ZONES)
    response_format = endpoint.requests[0]["body"]["response_format"]
    assert response_format["type"] == "json_schema"
    assert response_format["json_schema"]["name"] == "zone_rating" and response_format["json_schema"]["strict"] is False
    schema = response_format["json_schema"]["schema"]
    assert schema["type"] == "object"
    assert set(schema["required"]) == {"ratings", "preferred", "avoid", "approach", "grasp_style", "max_tilt_deg"}
    properties = schema["properties"]
    assert properties["ratings"]["additionalProperties"]["enum"] == list(RATING_LEVELS)
    assert properties["approach"]["enum"] == [a for a in APPROACH_NAMES if a != "vector"]
    assert properties["grasp_style"]["enum"] == list(GRASP_STYLES)
    assert properties["preferred"]["items"] == properties["avoid"]["items"] == {"type": "string"}
    assert set(properties["max_tilt_deg"]["type"]) == {"number", "null"}

    assert rating.provenance.outcome == "ok" and rating.provenance.output_mode == "json_schema"
    assert rating.provenance_dict()["output_mode"] == "json_schema", "trial records say how the answer was asked for"
    assert ZoneRating.from_dict(rating.to_dict()).provenance.output_mode == "json_schema"


def test_a_server_without_structured_output_is_asked_plainly_once_and_from_then_on(endpoint, tmp_path):
    endpoint.refuses_schema = True
    endpoint.script = [("answer", json.dumps(GOOD_ANSWER)), ("answer", json.dumps(GOOD_ANSWER))]
    rater = openai_rater(endpoint, tmp_path)
    rating = rater.rate("025_mug", "mug", "t2", CROP, ZONES)
    assert rating.provenance.outcome == "ok" and rating.provenance.output_mode == "plain"
    assert rating.preferred == {"protrusion"}
    refused, plain = endpoint.requests
    assert "response_format" in refused["body"] and "response_format" not in plain["body"]
    assert plain["body"] == {k: v for k, v in refused["body"].items() if k != "response_format"}, "the same request, less the schema"

    second = rater.rate("011_banana", "banana", "t1", CROP, ZONES)
    assert second.provenance.output_mode == "plain" and len(endpoint.requests) == 3
    assert "response_format" not in endpoint.requests[2]["body"], "the client remembers the refusal"


def test_a_refusal_for_another_reason_still_fails_and_is_not_remembered(endpoint, tmp_path):
    endpoint.refuses_schema = True
    endpoint.script = [("bad_request", None)]
    client = OpenAIVLM(RatingConfig(endpoint=endpoint.url, max_retries=0))
    with pytest.raises(VLMRequestError, match="HTTP 400"):
        client.generate_json(CROP, "hello", "zone_rating", {"type": "object"})
    assert len(endpoint.requests) == 2 and not client.schema_refused


def test_ratings_cached_before_the_output_mode_was_recorded_still_load():
    from sagp_batched.rating.zone_rating import ZoneRating

    stored = {**GOOD_ANSWER, "ratings": {"top": "bad"}, "approach_vector_world": None, "issues": [],
              "provenance": {"backend": "openai", "model": "m", "prompt_version": "v", "latency_s": 1.0, "outcome": "ok"}}
    assert ZoneRating.from_dict(stored).provenance.output_mode == ""
    stored["provenance"]["output_mode"] = "grammar"
    with pytest.raises(RatingError, match="output mode grammar"):
        ZoneRating.from_dict(stored)
    assert PriorRater().rate("025_mug", "mug", "t2", CROP, ZONES).provenance_dict()["output_mode"] == ""


def test_endpoint_fenced_answer_is_repaired(endpoint, tmp_path):
    endpoint.script = [("answer", "```json\n" + json.dumps(GOOD_ANSWER) + "\n```")]
    rating = openai_rater(endpoint, tmp_path).rate("025_mug", "mug", "t2", CROP, ZONES)
    assert rating.provenance.outcome == "repaired" and rating.avoid == {"top"}


def test_endpoint_garbage_is_neutral(endpoint, tmp_path):
    endpoint.script = [("answer", "The mug is a nice mug.")]
    rating = openai_rater(endpoint, tmp_path).rate("025_mug", "mug", "t2", CROP, ZONES)
    assert rating.is_neutral


def test_endpoint_500_then_success_is_retried(endpoint, tmp_path):
    endpoint.script = [("error", None), ("answer", json.dumps(GOOD_ANSWER))]
    rating = openai_rater(endpoint, tmp_path).rate("025_mug", "mug", "t2", CROP, ZONES)
    assert rating.provenance.outcome == "ok" and len(endpoint.requests) == 2


def test_endpoint_timeout_gives_up_after_bounded_retries(endpoint, tmp_path):
    endpoint.script = [("sleep", 1.0), ("sleep", 1.0)]
    rater = openai_rater(endpoint, tmp_path, timeout_s=0.2, max_retries=1)
    rating = rater.rate("025_mug", "mug", "t2", CROP, ZONES)
    assert rating.is_neutral and "no answer" in rating.issues[0] and "2 attempts" in rating.issues[0]
    assert len(endpoint.requests) == 2
    with pytest.raises(VLMRequestError, match="ReadTimeout"):
        endpoint.script = [("sleep", 1.0)]
        OpenAIVLM(RatingConfig(endpoint=endpoint.url, timeout_s=0.2, max_retries=0)).generate(CROP, "hello")


def test_unreachable_endpoint_is_neutral_not_a_crash(tmp_path):
    config = RatingConfig(backend="openai", endpoint="http://127.0.0.1:9/v1", timeout_s=0.5, max_retries=1,
                          retry_backoff_s=0.01, use_cache=False)
    rating = get_rater(config).rate("025_mug", "mug", "t1", CROP, ZONES)
    assert rating.is_neutral and "ConnectError" in rating.issues[0]


def test_bad_requests_are_named():
    # Requests are checked before any model is asked, so a client that could never answer is enough.
    rater = VLMRater("openai", "m", 15.0, lambda: OpenAIVLM(RatingConfig(endpoint="http://127.0.0.1:9/v1")))
    with pytest.raises(RatingError, match="unknown task 't9'"):
        rater.rate("025_mug", "mug", "t9", CROP, ZONES)
    with pytest.raises(RatingError, match="crop_rgb"):
        rater.rate("025_mug", "mug", "t1", CROP[..., 0], ZONES)
    with pytest.raises(RatingError, match="unknown zones"):
        rater.rate("025_mug", "mug", "t1", CROP, {"handle": "the handle"})
    with pytest.raises(ConfigError, match="rating.backend: unknown value 'crystal_ball'"):
        get_rater(RatingConfig(backend="crystal_ball"))


# --- prior and cache.

def test_prior_covers_the_study_and_names_itself_a_prior():
    rater = PriorRater()
    mug = rater.rate("025_mug", "mug", "t2", CROP, ZONES)
    assert mug.provenance.backend == "prior" and mug.provenance.outcome == "ok"
    assert mug.ratings["protrusion"] == "good" and "top" in mug.avoid and mug.max_tilt_deg == 15.0
    scissors = rater.rate("037_scissors", "scissors", "t2", CROP, ZONES)
    assert scissors.prefers("wide_end") and scissors.level("narrow_end") == "dangerous"
    for object_id in STUDY_OBJECTS:
        for task in TASKS:
            assert not rater.rate(object_id, object_id, task, CROP, ZONES).is_neutral
    unknown = rater.rate("999_teapot", "teapot", "t1", CROP, ZONES)
    assert unknown.is_neutral and unknown.provenance.backend == "prior"


def test_cache_asks_42_questions_once_and_reasks_corrupt_entries(tmp_path):
    first = CachedRater(PriorRater(), tmp_path)
    answers = {(o, t): first.rate(o, o, t, CROP, ZONES) for o in STUDY_OBJECTS for t in TASKS}
    assert first.queries == 42 and len(list(tmp_path.glob("*.json"))) == 42

    rerun = CachedRater(PriorRater(), tmp_path)
    again = {(o, t): rerun.rate(o, o, t, CROP, ZONES) for o in STUDY_OBJECTS for t in TASKS}
    assert rerun.queries == 0
    assert again == answers and all(r.provenance.cached for r in again.values())

    mug_t2 = rerun._path("025_mug", "t2")
    mug_t2.write_text(mug_t2.read_text()[:40])  # torn write
    banana_t1 = rerun._path("011_banana", "t1")
    tampered = json.loads(banana_t1.read_text())
    tampered["rating"]["ratings"]["middle"] = "dangerous"  # edited without its hash
    banana_t1.write_text(json.dumps(tampered))
    repaired = CachedRater(PriorRater(), tmp_path)
    assert repaired.rate("025_mug", "mug", "t2", CROP, ZONES) == answers[("025_mug", "t2")]
    assert repaired.rate("011_banana", "banana", "t1", CROP, ZONES).ratings["middle"] == "good"
    assert repaired.queries == 2
    assert CachedRater(PriorRater(), tmp_path).rate("025_mug", "mug", "t2", CROP, ZONES).provenance.cached


def test_cache_keys_separate_backends_models_and_prompt_versions(tmp_path):
    prior = CachedRater(PriorRater(), tmp_path)
    assert prior._path("025_mug", "t1") != prior._path("025_mug", "t2")
    other = CachedRater(PriorRater(), tmp_path)
    other.model = "another-table.json"
    assert other._path("025_mug", "t1") != prior._path("025_mug", "t1")


def test_a_rating_cached_from_one_endpoint_is_not_served_for_another(tmp_path):
    good, garbage = ScriptedEndpoint(), ScriptedEndpoint()
    try:
        good.script = [("answer", json.dumps(GOOD_ANSWER))]
        first = openai_rater(good, tmp_path, use_cache=True)
        assert not first.rate("025_mug", "mug", "t2", CROP, ZONES).is_neutral and first.queries == 1

        garbage.script = [("answer", "V]oB}l\"XoBg}l#e]oBg}")]
        other = openai_rater(garbage, tmp_path, use_cache=True)
        rating = other.rate("025_mug", "mug", "t2", CROP, ZONES)
        assert other.queries == 1 and len(garbage.requests) == 1, "the other endpoint is asked itself"
        assert rating.is_neutral and not rating.provenance.cached

        good.url += "/"  # the same server, written with a trailing slash
        trailing_slash = openai_rater(good, tmp_path, use_cache=True)
        assert trailing_slash.rate("025_mug", "mug", "t2", CROP, ZONES).provenance.cached and trailing_slash.queries == 0
    finally:
        for server in (good, garbage):
            server.server.shutdown()
            server.server.server_close()


class ScriptedZoneClient:
    backend, model = "openai", "served-vlm"

    def __init__(self, text: str):
        self.text = text

    def generate_json(self, image, prompt, schema_name, schema):
        return ModelAnswer(self.text, "json_schema")


def test_an_entry_is_served_only_for_the_key_it_records(tmp_path):
    def rater(endpoint, text):
        return CachedRater(VLMRater("openai", "served-vlm", 15.0, lambda: ScriptedZoneClient(text), endpoint=endpoint), tmp_path)

    # An entry whose key names no endpoint (as an endpoint-less rater writes it) answers no endpoint's question.
    rater("", json.dumps(GOOD_ANSWER)).rate("025_mug", "mug", "t2", CROP, ZONES)
    served_b = rater("http://b.example/v1", "garbage")
    assert served_b.rate("025_mug", "mug", "t2", CROP, ZONES).is_neutral and served_b.queries == 1

    # Nor does an entry found at another key's path.
    served_a = rater("http://a.example/v1", json.dumps(GOOD_ANSWER))
    served_a.rate("025_mug", "mug", "t2", CROP, ZONES)
    served_a._path("025_mug", "t2").replace(served_b._path("025_mug", "t2"))
    assert served_b.rate("025_mug", "mug", "t2", CROP, ZONES).is_neutral and served_b.queries == 2
    assert json.loads(served_b._path("025_mug", "t2").read_text())["key"]["endpoint"] == "http://a.example/v1"


# --- VLM-Direct asks through the same generate primitive of both model backends.

def test_vlm_direct_through_the_local_vlm_and_the_endpoint(tiny_qwen2_vl, endpoint):
    from test_rating_vlm_direct import candidates, cloud

    from sagp_batched.config import Config
    from sagp_batched.semantics.vlm_direct import get_vd_client, vlm_direct_rank

    unranked = candidates(12)
    batch = unranked.ranked_by(unranked.s_geom)
    local = Config().override("rating", backend="transformers", model=str(tiny_qwen2_vl), max_new_tokens=16)
    result = vlm_direct_rank(cloud(), batch, get_vd_client(local.rating), local, "t1", "mug")
    assert result.backend == "transformers" and result.latency_s > 0.0
    assert sorted(result.order) == list(range(12)), "garbage or not, every candidate keeps a place"

    endpoint.script = [("answer", '{"ranking": [2, 7]}')]
    served = Config().override("rating", backend="openai", endpoint=endpoint.url, model="served-vlm")
    result = vlm_direct_rank(cloud(), batch, get_vd_client(served.rating), served, "t1", "mug")
    assert result.order[:2] == [1, 6] and result.n_from_model == 2
    assert "1 to 12" in endpoint.requests[0]["body"]["messages"][0]["content"][1]["text"]
    assert "response_format" not in endpoint.requests[0]["body"], "VLM-Direct's ranking is free text, not a zone rating"


def test_a_fully_cached_rerun_never_loads_the_model(tmp_path):
    class Scripted:
        backend, model = "transformers", "some-vlm"

        def generate(self, image, prompt):
            return json.dumps(GOOD_ANSWER)

        def generate_json(self, image, prompt, schema_name, schema):
            return ModelAnswer(self.generate(image, prompt), "plain")

    def refuse():
        raise AssertionError("the model was loaded although every answer is cached")

    first = CachedRater(VLMRater("transformers", "some-vlm", 15.0, Scripted), tmp_path)
    asked = first.rate("025_mug", "mug", "t2", CROP, ZONES)
    rerun = CachedRater(VLMRater("transformers", "some-vlm", 15.0, refuse), tmp_path)
    assert rerun.rate("025_mug", "mug", "t2", CROP, ZONES) == asked and rerun.queries == 0


def test_the_oracle_rates_the_mug_handle_zone_good_and_is_labelled_an_upper_bound():
    from sagp_batched.config import RatingConfig
    from sagp_batched.world.functional_regions import load_regions
    from sagp_batched.rating import get_rater
    from sagp_batched.study.study_report import rater_note

    oracle = get_rater(RatingConfig(backend="oracle"))
    assert oracle.uses_ground_truth and "upper bound" in oracle.model
    mug = load_regions()["025_mug"]
    handle_box, rim_box = mug.functional[0], mug.avoid[0]
    rng = np.random.default_rng(0)
    handle_points = rng.uniform(handle_box.min, handle_box.max, (50, 3))
    rim_points = rng.uniform(rim_box.min, rim_box.max, (50, 3))
    zones = {
        "protrusion_1": handle_points, "top": np.concatenate([rim_points, handle_points[:10]]), "middle": np.zeros((30, 3)),
        # Some rim, the rest elsewhere: bad. Rim and handle in equal shares: says nothing either way.
        "bottom": np.concatenate([rim_points[:15], np.zeros((35, 3))]), "narrow_end": np.concatenate([rim_points[:20], handle_points[:15], np.zeros((15, 3))]),
        # A side half crosses every third: not rated by its content.
        "left": handle_points,
    }
    rating = oracle.rate("025_mug", "mug", "t2", np.zeros((4, 4, 3), np.uint8), {}, zones)
    assert rating.level("protrusion_1") == "good" and rating.prefers("protrusion_1")
    assert rating.level("top") == "dangerous" and rating.avoids("top")
    assert rating.level("middle") == "acceptable" and rating.max_tilt_deg == 15.0
    assert rating.level("bottom") == "bad" and rating.level("narrow_end") == "acceptable"
    assert rating.level("left") == "acceptable" and not rating.prefers("left")
    assert oracle.rate("005_tomato_soup_can", "can", "t2", np.zeros((4, 4, 3), np.uint8), {}, zones).is_neutral
    assert "UPPER BOUND" in rater_note([{"rating": rating.provenance_dict()}])


# --- what the model sees: the zones drawn on the crop (set-of-mark prompting), and kept beside the cache.

def marked_scene():
    from test_zone_marks import synthetic_cloud

    from sagp_batched.semantics.zones import decompose

    cloud = synthetic_cloud()
    return cloud, decompose(cloud.points_world)


def sent_image_and_prompt(request) -> tuple[np.ndarray, str]:
    content = request["body"]["messages"][0]["content"]
    image_url = content[0]["image_url"]["url"]
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(image_url.split(",", 1)[1])))), content[1]["text"]


def test_the_endpoint_is_shown_the_marked_crop_and_told_to_use_the_marks(endpoint, tmp_path):
    from sagp_batched.rating import PROMPT_VERSION
    from sagp_batched.semantics.zone_marks import draw_zone_marks, rating_image

    cloud, zones = marked_scene()
    endpoint.script = [("answer", json.dumps(GOOD_ANSWER)), ("answer", json.dumps(GOOD_ANSWER))]
    marked = openai_rater(endpoint, tmp_path)
    assert marked.prompt_version == f"{PROMPT_VERSION}-marks"
    rating = marked.rate("025_mug", "mug", "t2", rating_image(cloud, zones, RatingConfig()), describe_zones(zones))
    assert rating.provenance.outcome == "ok" and rating.provenance.prompt_version == f"{PROMPT_VERSION}-marks"
    sent, prompt = sent_image_and_prompt(endpoint.requests[0])
    assert np.array_equal(sent, draw_zone_marks(cloud, zones, RatingConfig()).image)
    assert sent.shape != cloud.crop_rgb.shape
    assert "coloured dots" in prompt and "labelled with its zone name" in prompt and "protrusion_1" in prompt

    plain = openai_rater(endpoint, tmp_path, zone_marks=False)
    assert plain.prompt_version == PROMPT_VERSION
    plain.rate("025_mug", "mug", "t2", rating_image(cloud, zones, RatingConfig(zone_marks=False)), describe_zones(zones))
    sent, prompt = sent_image_and_prompt(endpoint.requests[1])
    assert np.array_equal(sent, cloud.crop_rgb) and "coloured dots" not in prompt


def test_the_local_vlm_rates_a_marked_crop_end_to_end(tiny_qwen2_vl, tmp_path):
    from sagp_batched.rating import PROMPT_VERSION
    from sagp_batched.semantics.zone_marks import rating_image

    cloud, zones = marked_scene()
    config = RatingConfig(backend="transformers", model=str(tiny_qwen2_vl), max_new_tokens=16, cache_dir=str(tmp_path))
    assert config.zone_marks, "marks are on by default"
    image = rating_image(cloud, zones, config)
    assert image.shape[0] >= config.vd_image_min_side_px
    rating = get_rater(config).rate("025_mug", "mug", "t2", image, describe_zones(zones))
    assert rating.provenance.backend == "transformers" and rating.provenance.prompt_version == f"{PROMPT_VERSION}-marks"
    assert rating.raw_text and rating.provenance.latency_s > 0.0


def test_the_image_a_rating_was_given_is_saved_beside_its_cache_entry(tmp_path):
    from sagp_batched.semantics.zone_marks import draw_zone_marks

    cloud, zones = marked_scene()
    shown = draw_zone_marks(cloud, zones, RatingConfig()).image
    rater = CachedRater(PriorRater(), tmp_path)
    rater.rate("025_mug", "mug", "t2", shown, describe_zones(zones))
    entry = rater._path("025_mug", "t2")
    assert entry.is_file() and entry.with_suffix(".png").is_file()
    assert np.array_equal(np.asarray(Image.open(entry.with_suffix(".png"))), shown)
    rater.rate("999_teapot", "teapot", "t1", shown, describe_zones(zones))  # neutral: neither stored nor pictured
    assert not rater._path("999_teapot", "t1").with_suffix(".png").exists()
    assert sorted(p.suffix for p in tmp_path.iterdir()) == [".json", ".png"], "no temporary file is left behind"
