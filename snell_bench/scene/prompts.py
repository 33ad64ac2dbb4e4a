"""Every prompt of the method from one prompt with a marked object phrase.

The user marks the phrase that places the glass object with double square brackets (config key
``scene.text``); :func:`decompose` turns the marked prompt into :class:`Prompts` (p, p⁻, p³⁶⁰, p_obj,
the noun, the materials, the surface and the scene) by the rules of
:mod:`snell_bench.scene.prompt_rules`. :func:`decompose_with_llm`
(:mod:`snell_bench.scene.prompt_llm`) asks a local text-generation model to mark an unmarked prompt
first.
"""

from __future__ import annotations

from snell_bench.scene.prompt_llm import LLM_INSTRUCTION, decompose_with_llm
from snell_bench.scene.prompt_rules import GROUND_NOUNS, MATERIAL_WORDS, PANO_PREFIX, SUPPORT_NOUNS, Prompts, decompose

__all__ = [
    "GROUND_NOUNS",
    "LLM_INSTRUCTION",
    "MATERIAL_WORDS",
    "PANO_PREFIX",
    "SUPPORT_NOUNS",
    "Prompts",
    "decompose",
    "decompose_with_llm",
]
