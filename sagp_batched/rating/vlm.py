"""Vision-language model clients sharing one primitive, ``generate(image, prompt) -> text``.

Both the zone rater and VLM-Direct talk to a model only through this primitive.
"""
from __future__ import annotations

import base64
import io
import logging
import os
import time
from pathlib import Path
from typing import Protocol

import httpx
import numpy as np
import torch
from PIL import Image

from ..config import RatingConfig
from .prompt import checked_image
from .types import RatingError, VLMRequestError

log = logging.getLogger(__name__)


class VLMClient(Protocol):
    backend: str
    model: str

    def generate(self, image: np.ndarray, prompt: str) -> str:
        """The model's answer to ``prompt`` about ``image`` ((H, W, 3) uint8); raises ``VLMRequestError``."""
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


class OpenAIVLM:
    """Any OpenAI-compatible chat-completions endpoint (vLLM, Ollama, LM Studio, hosted)."""

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

    def generate(self, image: np.ndarray, prompt: str) -> str:
        buffer = io.BytesIO()
        Image.fromarray(checked_image(image, "image")).save(buffer, format="PNG")
        data_url = "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")
        payload = {
            "model": self.model,
            "temperature": 0.0,
            "max_tokens": self.max_new_tokens,
            "messages": [{"role": "user", "content": [
                {"type": "image_url", "image_url": {"url": data_url}},
                {"type": "text", "text": prompt},
            ]}],
        }
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
            if response.status_code >= 500 or response.status_code == 429:
                failures.append(f"attempt {attempt + 1}: HTTP {response.status_code}")
                log.warning("%s: %s", self.url, failures[-1])
                continue
            if response.status_code != 200:
                raise VLMRequestError(f"{self.url} refused the request: HTTP {response.status_code} {response.text[:200]}")
            try:
                content = response.json()["choices"][0]["message"]["content"]
            except (ValueError, KeyError, IndexError, TypeError) as exc:
                raise VLMRequestError(f"{self.url} answered a malformed completion: {response.text[:200]!r}") from exc
            if not isinstance(content, str):
                raise VLMRequestError(f"{self.url} answered non-text content: {content!r:.200}")
            return content
        raise VLMRequestError(f"{self.url} gave no answer after {self.max_retries + 1} attempts ({'; '.join(failures)})")


def get_vlm_client(config: RatingConfig) -> VLMClient:
    """The model client of ``config.backend``; the ``prior`` backend has none (``RatingError``)."""
    if config.backend == "transformers":
        return TransformersVLM(config)
    if config.backend == "openai":
        return OpenAIVLM(config)
    raise RatingError(f"rating backend '{config.backend}' has no vision-language model (model backends: transformers, openai)")
