"""Vision-language model backends, shared by the VLM decomposer and the VLM labeler.

An OpenAI-compatible ``/chat/completions`` endpoint (base URL and model from config, API key read
from an environment variable and never logged) and a local transformers VLM checkpoint; each
answers one prompt made of text and images. Every failure is a :class:`VLMError` whose one-line
message names the endpoint (or checkpoint).
"""

from __future__ import annotations

import base64
import io
import json
import logging
import os
import time
import urllib.error
import urllib.request
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from rdd.checks import check_options, number, whole
from rdd.errors import InputError
from rdd.registry import component, register

log = logging.getLogger(__name__)


class VLMError(RuntimeError):
    """The VLM backend failed or answered with nothing usable."""


def subsample_indices(num_frames: int, max_frames: int) -> np.ndarray:
    """Up to ``max_frames`` evenly spaced frame indices, always including the first and last."""
    if num_frames < 1:
        raise ValueError("cannot subsample an episode with no frames")
    if max_frames < 2:
        raise ValueError(f"max_frames must be at least 2, got {max_frames}")
    if num_frames <= max_frames:
        return np.arange(num_frames)
    return np.unique(np.linspace(0, num_frames - 1, max_frames).round().astype(np.int64))


def encode_png(image: np.ndarray) -> str:
    """Base64 PNG of a uint8 RGB image."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image)).save(buf, format="PNG")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def resize_max_side(images: np.ndarray, max_side: int | None) -> list[np.ndarray]:
    """Images downsized (PIL bilinear) so their longer side is at most ``max_side``."""
    from PIL import Image

    out = []
    for img in images:
        h, w = img.shape[:2]
        if max_side is not None and max(h, w) > max_side:
            s = max_side / max(h, w)
            img = np.asarray(Image.fromarray(img).resize((max(1, round(w * s)), max(1, round(h * s))),
                                                       Image.BILINEAR))
        out.append(img)
    return out


class VLMBackend(Protocol):
    """Answers one prompt made of text and images."""

    name: str

    def ask(self, prompt: str, images: Sequence[np.ndarray], labels: Sequence[str]) -> str:
        """The model's text answer to ``prompt`` followed by ``labels[i]`` + ``images[i]``."""
        ...


@register("vlm_backend", "openai")
class OpenAIChatBackend:
    """An OpenAI-compatible chat-completions endpoint (``{base_url}/chat/completions``)."""

    name = "openai"
    OPTION_RULES = {"timeout": number(0.0, exclusive_min=True), "retries": whole(0), "backoff": number(0.0),
                    "max_tokens": whole(1), "temperature": number(0.0, 2.0)}

    def __init__(
        self,
        base_url: str = "",  # required: refused below with the option's name when missing
        model: str = "",
        api_key_env: str | None = "OPENAI_API_KEY",
        timeout: float = 60.0,
        retries: int = 2,
        backoff: float = 1.0,
        max_tokens: int = 256,
        temperature: float = 0.0,
    ):
        if not base_url:
            raise ValueError("the openai VLM backend needs base_url (e.g. http://127.0.0.1:8000/v1)")
        if not model:
            raise ValueError("the openai VLM backend needs model (the served model's name)")
        opts = check_options("VLM backend openai", self.OPTION_RULES, {
            "timeout": timeout, "retries": retries, "backoff": backoff, "max_tokens": max_tokens,
            "temperature": temperature})
        self.url = base_url.rstrip("/") + "/chat/completions"
        self.model = model
        self.api_key_env = api_key_env
        self.timeout, self.retries, self.backoff = opts["timeout"], opts["retries"], opts["backoff"]
        self.max_tokens, self.temperature = opts["max_tokens"], opts["temperature"]
        self._warned_no_key = False

    def _headers(self) -> dict[str, str]:
        headers = {"Content-Type": "application/json"}
        if self.api_key_env:
            key = os.environ.get(self.api_key_env)
            if key:
                headers["Authorization"] = f"Bearer {key}"
            elif not self._warned_no_key:
                self._warned_no_key = True
                log.warning("environment variable %s is not set; calling %s without an API key",
                            self.api_key_env, self.url)
        return headers

    def ask(self, prompt: str, images: Sequence[np.ndarray], labels: Sequence[str]) -> str:
        """POST the prompt and images; retry on timeouts, connection errors, 429 and 5xx."""
        content: list[dict[str, Any]] = [{"type": "text", "text": prompt}]
        for label, img in zip(labels, images, strict=True):
            content.append({"type": "text", "text": label})
            content.append({"type": "image_url",
                            "image_url": {"url": f"data:image/png;base64,{encode_png(img)}"}})
        body = json.dumps({
            "model": self.model,
            "messages": [{"role": "user", "content": content}],
            "max_tokens": self.max_tokens,
            "temperature": self.temperature,
        }).encode()
        last: str = ""
        for attempt in range(self.retries + 1):
            if attempt:
                time.sleep(self.backoff * 2 ** (attempt - 1))
            request = urllib.request.Request(self.url, data=body, headers=self._headers(), method="POST")
            try:
                with urllib.request.urlopen(request, timeout=self.timeout) as resp:
                    payload = json.loads(resp.read().decode("utf-8"))
            except urllib.error.HTTPError as exc:
                last = f"HTTP {exc.code} {exc.reason}"
                if exc.code == 429 or exc.code >= 500:
                    log.warning("VLM endpoint %s: %s (attempt %d)", self.url, last, attempt + 1)
                    continue
                raise VLMError(f"VLM endpoint {self.url} refused the request: {last}") from None
            except (urllib.error.URLError, TimeoutError, ConnectionError, OSError) as exc:
                last = f"{type(exc).__name__}: {getattr(exc, 'reason', exc)}"
                log.warning("VLM endpoint %s: %s (attempt %d)", self.url, last, attempt + 1)
                continue
            except json.JSONDecodeError as exc:
                raise VLMError(f"VLM endpoint {self.url} answered with invalid JSON ({exc})") from None
            try:
                message = payload["choices"][0]["message"]["content"]
            except (KeyError, IndexError, TypeError):
                raise VLMError(
                    f"VLM endpoint {self.url}: answer lacks choices[0].message.content: "
                    f"{json.dumps(payload)[:200]}"
                ) from None
            if isinstance(message, list):  # some servers return content parts
                message = " ".join(str(p.get("text", "")) for p in message if isinstance(p, dict))
            return str(message)
        raise VLMError(f"VLM endpoint {self.url} failed after {self.retries + 1} attempts ({last})")


@register("vlm_backend", "transformers")
class TransformersVLMBackend:
    """A local transformers image-text-to-text checkpoint (e.g. a LLaVA or Qwen-VL folder)."""

    name = "transformers"
    OPTION_RULES = {"max_new_tokens": whole(1)}

    def __init__(self, checkpoint: str | Path, device: str = "cpu", max_new_tokens: int = 128):
        path = Path(checkpoint).expanduser() if checkpoint else None
        if path is None or not (path / "config.json").is_file():
            raise FileNotFoundError(
                f"VLM checkpoint {checkpoint!r} not found: put a transformers image-text-to-text "
                "checkpoint folder (config.json, weights, processor files) there and pass "
                "checkpoint=<folder>; nothing is downloaded"
            )
        try:
            import torch
            from transformers import AutoModelForImageTextToText, AutoProcessor
        except ImportError as exc:
            raise ImportError("the transformers VLM backend needs: pip install 'rdd[vlm]'") from exc
        self.torch = torch
        self.processor = AutoProcessor.from_pretrained(str(path), local_files_only=True)
        self.model = AutoModelForImageTextToText.from_pretrained(str(path), local_files_only=True)
        self.model.to(device).eval()
        self.device = device
        self.max_new_tokens = check_options("VLM backend transformers", self.OPTION_RULES,
                                            {"max_new_tokens": max_new_tokens})["max_new_tokens"]

    def ask(self, prompt: str, images: Sequence[np.ndarray], labels: Sequence[str]) -> str:
        """Greedy generation from the chat-templated prompt with the images interleaved."""
        from PIL import Image

        content: list[dict[str, Any]] = [{"type": "text", "text": prompt}]
        for label in labels:
            content += [{"type": "text", "text": label}, {"type": "image"}]
        text = self.processor.apply_chat_template(
            [{"role": "user", "content": content}], add_generation_prompt=True
        )
        inputs = self.processor(text=text, images=[Image.fromarray(i) for i in images], return_tensors="pt")
        inputs = {k: v.to(self.device) if hasattr(v, "to") else v for k, v in inputs.items()}
        with self.torch.inference_mode():
            out = self.model.generate(**inputs, max_new_tokens=self.max_new_tokens, do_sample=False)
        new_tokens = out[0, inputs["input_ids"].shape[1]:]
        return self.processor.decode(new_tokens, skip_special_tokens=True)


def check_backend_options(backend: str, own: Sequence[str] = (), **options: Any) -> type:
    """The backend class named ``backend``, after checking that it takes ``options`` and their ranges
    (``own``: the caller's own options, listed beside the backend's when one is unknown)."""
    import inspect

    try:
        cls = component("vlm_backend", backend)
    except ValueError as exc:
        raise InputError(str(exc), option="backend") from None
    accepted = [n for n in inspect.signature(cls).parameters if n != "self"]
    unknown = sorted(set(options) - set(accepted))
    if unknown:
        raise InputError(f"VLM backend {backend!r}: unknown option(s) {unknown}; accepted: "
                         f"{', '.join([*own, *accepted])}", option=unknown[0])
    check_options(f"VLM backend {backend}", cls.OPTION_RULES, options)
    return cls


def make_backend(backend: str, own: Sequence[str] = (), **options: Any) -> VLMBackend:
    """Build a backend by name: ``openai`` or ``transformers``; an option it does not take is an error."""
    return check_backend_options(backend, own, **options)(**options)
