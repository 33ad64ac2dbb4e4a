"""The optional language-model path of :mod:`snell_bench.scene.prompts`.

:func:`decompose_with_llm` asks a local text-generation model to mark the object phrase of an
unmarked prompt with ``[[...]]`` and then calls :func:`~snell_bench.scene.prompt_rules.decompose`.
Weights are read from local files only, never downloaded.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

from snell_bench.models.devices import resolve_device
from snell_bench.models.errors import WeightsNotFoundError
from snell_bench.scene.prompt_rules import CLOSE, EXAMPLE, LLM_KEY, OPEN, TEXT_KEY, Prompts, decompose

__all__ = ["LLM_INSTRUCTION", "decompose_with_llm"]

#: What :func:`decompose_with_llm` asks the model (``{text}`` is the unmarked prompt).
LLM_INSTRUCTION = """\
Mark the phrase of an image prompt that places the glass object in the scene with double square brackets [[...]].
Copy the prompt exactly and change nothing else. Mark exactly one phrase: the object with its placement words \
(such as "on top", "on the ground" or "on the table") and its trailing comma.

Prompt: A cozy living room with a polished wooden coffee table close to the camera, with a big glass sphere on top, \
surrounded by a beige sofa.
Marked: A cozy living room with a polished wooden coffee table close to the camera, [[with a big glass sphere on top,]] \
surrounded by a beige sofa.

Prompt: A rocky cave lit by a bright campfire, a big glass sphere on the ground, with scattered camping gear.
Marked: A rocky cave lit by a bright campfire, [[a big glass sphere on the ground,]] with scattered camping gear.

Prompt: {text}
Marked:"""

_REPO_ID = re.compile(r"^[A-Za-z0-9][\w.-]*/[\w.-]+$")
_MARKED = re.compile(r"\[\[(.+?)\]\]", re.DOTALL)
_SPACE = re.compile(r"\s+")


def _llm_weights_help(model_path: object, what: str) -> str:
    return (
        f"prompt LLM weights not found: {what}. Set the config key {LLM_KEY} to a local folder with a "
        f"transformers text-generation model (config.json, tokenizer and weights) or to a Hugging Face id "
        f"already in the local cache (got {model_path!r}); weights are never downloaded. Or mark the object "
        f"phrase by hand in {TEXT_KEY}, e.g. {EXAMPLE!r}"
    )


@lru_cache(maxsize=2)
def _load_llm(model_path: str, device: str):
    """``(tokenizer, model)`` from local files only; :class:`WeightsNotFoundError` when missing."""
    path = Path(model_path).expanduser()
    if path.is_dir():
        if not (path / "config.json").is_file():
            raise WeightsNotFoundError(_llm_weights_help(model_path, f"the folder {str(path)!r} has no config.json"))
        source = str(path)
    elif path.exists():
        raise WeightsNotFoundError(_llm_weights_help(model_path, f"{str(path)!r} is a file, not a model folder"))
    elif _REPO_ID.match(model_path):
        source = model_path
    else:
        raise WeightsNotFoundError(_llm_weights_help(model_path, f"no folder {model_path!r}"))

    dev = resolve_device(
        device,
        unavailable=f"the prompt LLM ({LLM_KEY}) needs CUDA and none is available; pass device='cpu'",
    )
    try:
        from transformers import AutoModelForCausalLM, AutoTokenizer

        tokenizer = AutoTokenizer.from_pretrained(source, local_files_only=True)
        model = AutoModelForCausalLM.from_pretrained(source, local_files_only=True)
    except (OSError, ValueError) as err:
        raise WeightsNotFoundError(_llm_weights_help(model_path, f"loading {source!r} failed: {err}")) from err
    return tokenizer, model.to(dev).eval()


def _llm_generate(model_path: str, device: str) -> Callable[[str], str]:
    """A greedy text-generation function ``instruction -> completion`` of a local model."""
    tokenizer, model = _load_llm(model_path, device)

    def generate(instruction: str) -> str:
        import torch

        if getattr(tokenizer, "chat_template", None):
            ids = tokenizer.apply_chat_template(
                [{"role": "user", "content": instruction}],
                add_generation_prompt=True,
                return_tensors="pt",
                return_dict=True,
            )["input_ids"]
        else:
            ids = tokenizer(instruction, return_tensors="pt")["input_ids"]
        ids = ids.to(model.device)
        with torch.no_grad():
            out = model.generate(
                ids,
                attention_mask=torch.ones_like(ids),
                max_new_tokens=2 * ids.shape[-1] // 3 + 64,
                do_sample=False,
                pad_token_id=tokenizer.pad_token_id or tokenizer.eos_token_id,
            )
        return tokenizer.decode(out[0, ids.shape[-1] :], skip_special_tokens=True)

    return generate


def _mark_from_output(text: str, output: str) -> str:
    """``text`` with the phrase the model marked in ``output`` bracketed (found in ``text`` itself, so
    the model cannot change the rest of the prompt)."""
    found = _MARKED.search(output)
    if found is None:
        raise ValueError(
            f"the prompt LLM ({LLM_KEY}) marked no [[...]] phrase for the prompt {text!r}; it answered "
            f"{output.strip()!r}. Mark the object phrase by hand in {TEXT_KEY}, e.g. {EXAMPLE!r}"
        )
    phrase = _SPACE.sub(" ", found.group(1)).strip()
    for candidate in (phrase, phrase.rstrip(",.;: ")):
        if not candidate:
            continue
        pattern = re.compile(r"\s+".join(re.escape(w) for w in candidate.split(" ")), re.IGNORECASE)
        m = pattern.search(text)
        if m:
            end = m.end()
            if text[end - 1] not in ",;" and text[end : end + 1] in (",", ";"):  # the comma inside, as written by hand
                end += 1
            return text[: m.start()] + OPEN + text[m.start() : end] + CLOSE + text[end:]
    raise ValueError(
        f"the prompt LLM ({LLM_KEY}) marked {phrase!r}, which is not part of the prompt {text!r}. Mark the "
        f"object phrase by hand in {TEXT_KEY}, e.g. {EXAMPLE!r}"
    )


def decompose_with_llm(
    text: str,
    *,
    model_path: str | os.PathLike | None,
    device: str = "cpu",
    generate: Callable[[str], str] | None = None,
    pano: str | None = None,
    surface: str | None = None,
    minus: str | None = None,
) -> Prompts:
    """:func:`decompose` of a prompt whose object phrase a local language model marks.

    The model gets :data:`LLM_INSTRUCTION` and answers the prompt in the marked form; the first
    ``[[...]]`` phrase of its answer is looked up in ``text`` itself (case and spacing aside) and
    bracketed there, so the rest of the prompt stays exactly as written. A prompt that is already
    marked goes to :func:`decompose` without the model.

    Args:
        text: the prompt, marked or not.
        model_path: a local folder of a transformers text-generation model, or a Hugging Face id in
            the local cache (config key ``scene.prompt_llm``); loaded with ``local_files_only=True``.
        device: where the model runs (``"cpu"``, ``"cuda"``, ...).
        generate: a function ``instruction -> answer`` used instead of loading ``model_path``.
        pano: passed to :func:`decompose`.
        surface: passed to :func:`decompose`.
        minus: passed to :func:`decompose`.

    Returns:
        The :class:`Prompts`.

    Raises:
        WeightsNotFoundError: naming ``scene.prompt_llm``, when the weights are not on this machine.
        ValueError: when the answer marks no phrase or one that is not in the prompt, or from
            :func:`decompose`.
    """
    overrides = {"pano": pano, "surface": surface, "minus": minus}
    if OPEN in text or CLOSE in text:
        return decompose(text, **overrides)
    if generate is None:
        if model_path is None or not os.fspath(model_path).strip():
            raise WeightsNotFoundError(_llm_weights_help(model_path, "no model given"))
        generate = _llm_generate(os.fspath(model_path), str(device))
    answer = generate(LLM_INSTRUCTION.format(text=text))
    return decompose(_mark_from_output(text, answer), **overrides)
