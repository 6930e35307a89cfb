"""Vision-language model clients sharing two primitives: ``generate(image, prompt) -> text`` (free
text, what VLM-Direct asks) and ``generate_json(image, prompt, schema_name, schema) -> ModelAnswer``
(an answer that should match a JSON schema, what the zone rater asks).

A client constrains the answer to the schema where its server offers structured output and says
in ``ModelAnswer.output_mode`` whether it did ("json_schema") or asked with the prompt alone ("plain").
"""
from __future__ import annotations

import base64
import io
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import httpx
import numpy as np
import torch
from PIL import Image

from ..config import RatingConfig
from .prompt import checked_image
from .zone_rating import RatingError, VLMRequestError

log = logging.getLogger(__name__)


# Servers name the feature they refuse in different words: vLLM "guided decoding", others the field.
SCHEMA_REFUSAL_MARKERS: tuple[str, ...] = ("response_format", "json_schema", "guided")


@dataclass(frozen=True)
class ModelAnswer:
    text: str
    output_mode: str  # "json_schema" | "plain" (``types.OUTPUT_MODES`` less "")


class VLMClient(Protocol):
    backend: str
    model: str

    def generate(self, image: np.ndarray, prompt: str) -> str:
        """The model's answer to ``prompt`` about ``image`` ((H, W, 3) uint8); raises ``VLMRequestError``."""
        ...

    def generate_json(self, image: np.ndarray, prompt: str, schema_name: str, schema: dict[str, Any]) -> ModelAnswer:
        """The model's answer to ``prompt`` about ``image``, constrained to the JSON ``schema`` (named
        ``schema_name``, as servers require) where the backend can (``output_mode`` "json_schema"), else
        asked with the prompt alone ("plain"); raises ``VLMRequestError``."""
        ...


class TransformersVLM:
    """A local Qwen2-VL / Qwen2.5-VL checkpoint (hub id or directory) run with greedy decoding.

    Inputs are assembled from the image processor and the tokenizer directly because the combined
    Qwen processors need torchvision, which this stack must not install.
    """

    backend = "transformers"

    def __init__(self, config: RatingConfig):
        from transformers import AutoModelForImageTextToText, AutoTokenizer, Qwen2VLImageProcessorPil

        self.model = config.model
        self.max_new_tokens = config.max_new_tokens
        source = self._source(config.model)
        try:
            self._model = AutoModelForImageTextToText.from_pretrained(source, local_files_only=config.local_files_only)
            self._tokenizer = AutoTokenizer.from_pretrained(source, local_files_only=config.local_files_only)
            self._image_processor = Qwen2VLImageProcessorPil.from_pretrained(source, local_files_only=config.local_files_only)
        except OSError as exc:
            raise RatingError(
                f"cannot load VLM '{config.model}' (local_files_only={config.local_files_only}): {exc}"
            ) from exc
        self._model.eval()
        for attribute in ("image_token_id", "vision_start_token_id", "vision_end_token_id"):
            if getattr(self._model.config, attribute, None) is None:
                raise RatingError(f"model '{config.model}' is not a Qwen-VL model: its config lacks {attribute}")

    @staticmethod
    def _source(model: str) -> str:
        """A local directory when ``model`` names one, else the hub id as given."""
        local = Path(model).expanduser()
        return str(local) if local.exists() else model

    @classmethod
    def check_loadable(cls, config: RatingConfig) -> None:
        """Raise ``RatingError`` unless the model's config loads; reads no weights (a preflight, seconds)."""
        from transformers import AutoConfig

        source = cls._source(config.model)
        # A path that is not there would otherwise be reported as a malformed hub id.
        if config.model.startswith(("/", ".", "~")) and not Path(source).exists():
            raise RatingError(f"cannot load VLM '{config.model}': no such directory")
        try:
            AutoConfig.from_pretrained(source, local_files_only=config.local_files_only)
        except (OSError, ValueError) as exc:
            raise RatingError(
                f"cannot load VLM '{config.model}' (local_files_only={config.local_files_only}): {exc}"
            ) from exc

    def _token(self, token_id: int) -> str:
        return self._tokenizer.convert_ids_to_tokens(int(token_id))

    def generate(self, image: np.ndarray, prompt: str) -> str:
        pixels = self._image_processor(images=[Image.fromarray(checked_image(image, "image"))], return_tensors="pt")
        grid = pixels["image_grid_thw"]
        n_image_tokens = int(grid.prod()) // self._image_processor.merge_size**2
        config = self._model.config
        vision = (
            self._token(config.vision_start_token_id)
            + self._token(config.image_token_id) * n_image_tokens
            + self._token(config.vision_end_token_id)
        )
        # Qwen-VL chat format, as its chat template renders one user turn with one image.
        text = f"<|im_start|>user\n{vision}{prompt}<|im_end|>\n<|im_start|>assistant\n"
        encoded = self._tokenizer(text, return_tensors="pt")
        mm_token_type_ids = (encoded.input_ids == config.image_token_id).long()
        try:
            with torch.inference_mode():
                output = self._model.generate(
                    input_ids=encoded.input_ids, attention_mask=encoded.attention_mask,
                    pixel_values=pixels["pixel_values"], image_grid_thw=grid, mm_token_type_ids=mm_token_type_ids,
                    max_new_tokens=self.max_new_tokens, do_sample=False,
                )
        except (RuntimeError, ValueError) as exc:
            raise VLMRequestError(f"generation with '{self.model}' failed: {exc}") from exc
        return self._tokenizer.decode(output[0, encoded.input_ids.shape[1]:], skip_special_tokens=True)

    def generate_json(self, image: np.ndarray, prompt: str, schema_name: str, schema: dict[str, Any]) -> ModelAnswer:
        # Greedy decoding here has no grammar constraint; the prompt alone asks for the JSON.
        return ModelAnswer(self.generate(image, prompt), "plain")


class OpenAIVLM:
    """Any OpenAI-compatible chat-completions endpoint (vLLM, Ollama, LM Studio, hosted).

    ``generate_json`` sends the schema as ``response_format`` (``json_schema``, not strict: the format
    vLLM, Ollama and OpenAI accept). A server that refuses it (HTTP 400/422, or an error naming the
    feature) is asked the same request once more without it, and once that plain request is answered
    this client asks plainly from then on (``schema_refused``).
    """

    backend = "openai"

    def __init__(self, config: RatingConfig):
        self.model = config.model
        self.endpoint = config.endpoint.rstrip("/")
        self.url = self.endpoint + "/chat/completions"
        self.max_retries = config.max_retries
        self.retry_backoff_s = config.retry_backoff_s
        self.max_new_tokens = config.max_new_tokens
        key = os.environ.get(config.api_key_env, "")
        # Local servers take no key; sending none is what they expect.
        headers = {"Authorization": f"Bearer {key}"} if key else {}
        self._client = httpx.Client(timeout=config.timeout_s, headers=headers)
        self.schema_refused = False

    def served_models(self) -> list[str]:
        """The model ids ``GET {endpoint}/models`` lists: one request, no retries; raises ``VLMRequestError``."""
        url = self.endpoint + "/models"
        try:
            response = self._client.get(url)
        except httpx.HTTPError as exc:
            raise VLMRequestError(f"{url} did not answer: {type(exc).__name__}: {exc}") from exc
        if not response.is_success:
            raise VLMRequestError(f"{url} refused the request: HTTP {response.status_code} {response.text[:200]}")
        try:
            return [str(entry["id"]) for entry in response.json()["data"]]
        except (ValueError, KeyError, TypeError) as exc:
            raise VLMRequestError(f"{url} answered no model list: {response.text[:200]!r}") from exc

    def _payload(self, image: np.ndarray, prompt: str) -> dict[str, Any]:
        buffer = io.BytesIO()
        Image.fromarray(checked_image(image, "image")).save(buffer, format="PNG")
        data_url = "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")
        return {
            "model": self.model,
            "temperature": 0.0,
            "max_tokens": self.max_new_tokens,
            "messages": [{"role": "user", "content": [
                {"type": "image_url", "image_url": {"url": data_url}},
                {"type": "text", "text": prompt},
            ]}],
        }

    @staticmethod
    def _refuses_schema(response: httpx.Response) -> bool:
        """The server refused a request that carried ``response_format`` because of it (or may have: any 400/422)."""
        if response.status_code in (400, 422):
            return True
        text = response.text.lower()
        return response.status_code != 200 and any(marker in text for marker in SCHEMA_REFUSAL_MARKERS)

    def _post(self, payload: dict[str, Any]) -> httpx.Response:
        """The first response that is not a transient failure (transport error, 5xx, 429), retried with
        backoff; a refusal of ``response_format`` is returned, not retried. Raises ``VLMRequestError``."""
        failures: list[str] = []
        for attempt in range(self.max_retries + 1):
            if attempt:
                time.sleep(self.retry_backoff_s * 2 ** (attempt - 1))
            try:
                response = self._client.post(self.url, json=payload)
            except httpx.TransportError as exc:
                failures.append(f"attempt {attempt + 1}: {type(exc).__name__}")
                log.warning("%s: %s", self.url, failures[-1])
                continue
            transient = response.status_code >= 500 or response.status_code == 429
            if transient and not ("response_format" in payload and self._refuses_schema(response)):
                failures.append(f"attempt {attempt + 1}: HTTP {response.status_code}")
                log.warning("%s: %s", self.url, failures[-1])
                continue
            return response
        raise VLMRequestError(f"{self.url} gave no answer after {self.max_retries + 1} attempts ({'; '.join(failures)})")

    def _content(self, response: httpx.Response) -> str:
        """The completion's text; ``VLMRequestError`` for a refusal or a malformed completion."""
        if response.status_code != 200:
            raise VLMRequestError(f"{self.url} refused the request: HTTP {response.status_code} {response.text[:200]}")
        try:
            content = response.json()["choices"][0]["message"]["content"]
        except (ValueError, KeyError, IndexError, TypeError) as exc:
            raise VLMRequestError(f"{self.url} answered a malformed completion: {response.text[:200]!r}") from exc
        if not isinstance(content, str):
            raise VLMRequestError(f"{self.url} answered non-text content: {content!r:.200}")
        return content

    def generate(self, image: np.ndarray, prompt: str) -> str:
        return self._content(self._post(self._payload(image, prompt)))

    def generate_json(self, image: np.ndarray, prompt: str, schema_name: str, schema: dict[str, Any]) -> ModelAnswer:
        payload = self._payload(image, prompt)
        if self.schema_refused:
            return ModelAnswer(self._content(self._post(payload)), "plain")
        response_format = {"type": "json_schema", "json_schema": {"name": schema_name, "schema": schema, "strict": False}}
        response = self._post({**payload, "response_format": response_format})
        if not self._refuses_schema(response):
            return ModelAnswer(self._content(response), "json_schema")
        log.warning("%s refused structured output (HTTP %d %s); asking with the prompt alone",
                    self.url, response.status_code, response.text[:200])
        text = self._content(self._post(payload))
        # Only a plain request that is answered shows the schema was what the server refused.
        self.schema_refused = True
        return ModelAnswer(text, "plain")


def answer_endpoint(config: RatingConfig) -> str:
    """The server the answers of ``config.backend`` come from: the endpoint (without a trailing '/')
    for ``openai``; "" for the other backends, whose model path or hub id names their weights."""
    return config.endpoint.rstrip("/") if config.backend == "openai" else ""


def get_vlm_client(config: RatingConfig) -> VLMClient:
    """The model client of ``config.backend``; the ``prior`` backend has none (``RatingError``)."""
    if config.backend == "transformers":
        return TransformersVLM(config)
    if config.backend == "openai":
        return OpenAIVLM(config)
    raise RatingError(f"rating backend '{config.backend}' has no vision-language model (model backends: transformers, openai)")
